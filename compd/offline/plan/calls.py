"""The user's measuring cycle (`compd plan --probe-call`) as a value: one call
of a named macro or cycle with numeric arguments, nothing else.

The program runs the call between its own blocks, so the text the user gives
is never written as it is: it is parsed here into a name and numbers and the
block is written from them (`ProbeCall.block`). Anything else a block could
hold (a second word, a spindle or motion word, an ``M99``, a ``G10`` writing
a work offset, an ``O`` number, a comment) is refused with one line.

- FANUC (custom macro B): ``G65 P#### A… B… …``, the macro program 1-9999
  (not the program's own number), the arguments from FANUC's argument
  specification I (any address but G, L, N, O and P), each once, a number of
  at most 8 digits; a coordinate-like argument carries its decimal point
  (without one FANUC passes it in least increments, ``Z-10`` as -0.01 mm
  with IS-B), while D, H, M, S and T are whole numbers without one.
- SINUMERIK: one of Siemens' measuring cycles that measure with the linear
  axes, ``CYCLE978(0,1,,1,-10,100,,3,1)`` (arguments numbers or empty, at
  most 12 digits), or a subprogram by its number, ``L9810``, with no
  arguments. A name is not taken on trust: SINUMERIK's own procedures
  (``PUTFTOC``, ``SETAL``, ``CYCLE800`` which swivels the head…) read just
  like a user's cycle.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from decimal import Decimal

from compd.offline.plan.schedule import PlanError

_NUMBER = r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)"
#: FANUC's argument specification I: every address but G, L, N, O and P
FANUC_ARGUMENTS = frozenset("ABCDEFHIJKMQRSTUVWXYZ")
#: arguments FANUC passes as whole numbers: written without a decimal point
FANUC_WHOLE = frozenset("DHMST")
FANUC_MAX_DIGITS = 8
#: Siemens' measuring cycles of the linear axes (workpiece and tool, milling)
SINUMERIK_CYCLES = frozenset({"CYCLE971", "CYCLE973", "CYCLE974", "CYCLE976", "CYCLE977",
                              "CYCLE978", "CYCLE979", "CYCLE982", "CYCLE994", "CYCLE997",
                              "CYCLE998"})
SINUMERIK_MAX_DIGITS = 12
SINUMERIK_MAX_ARGUMENTS = 40


def _digits(text: str) -> int:
    return sum(c in "0123456789" for c in text)


def _number_text(value: Decimal, point: bool) -> str:
    """`value` as written in a block: no exponent, no sign on zero, and a
    trailing decimal point when `point` and it has no fraction (``-10.``)."""
    text = format(value.copy_abs() if value.is_zero() else value, "f")
    return text + "." if point and "." not in text else text


@dataclass(frozen=True)
class FanucMacro:
    """``G65 P<program> <address><value> …``."""

    program: int
    arguments: tuple[tuple[str, Decimal], ...]

    @property
    def block(self) -> str:
        words = [f"G65 P{self.program}"]
        words += [f"{a}{_number_text(v, a not in FANUC_WHOLE)}" for a, v in self.arguments]
        return " ".join(words)


@dataclass(frozen=True)
class SinumerikCall:
    """``NAME(arg, , arg…)`` or a subprogram ``L<number>``; None: an argument left out."""

    name: str
    arguments: tuple[Decimal | None, ...] | None

    @property
    def block(self) -> str:
        if self.arguments is None:
            return self.name
        args = ",".join("" if a is None else _number_text(a, False) for a in self.arguments)
        return f"{self.name}({args})"


ProbeCall = FanucMacro | SinumerikCall


def _refuse(call: str, why: str) -> PlanError:
    shown = ascii(call[:60]) + ("..." if len(call) > 60 else "")  # one line, any input
    return PlanError(f"--probe-call {shown}: {why}")


def parse_fanuc(call: str, own_program: int) -> FanucMacro:
    """The macro call in `call`, or PlanError naming what is wrong."""
    what = "one macro call G65 P<1-9999> with numeric arguments, e.g. 'G65 P9810 Z-10. F500.'"
    words = call.split()
    if len(words) < 2 or words[0] not in ("G65", "G065"):
        raise _refuse(call, f"{what}, nothing else")
    program = re.fullmatch(r"P([0-9]{1,4})", words[1])
    if program is None or not 1 <= int(program.group(1)) <= 9999:
        raise _refuse(call, f"the macro is P1 … P9999 ({what})")
    if int(program.group(1)) == own_program:
        raise _refuse(call, f"P{int(program.group(1))} is this program's own number "
                            f"(--program-number): it would call itself")
    arguments: list[tuple[str, Decimal]] = []
    for word in words[2:]:
        m = re.fullmatch(rf"([A-Z])({_NUMBER})", word)
        if m is None:
            raise _refuse(call, f"{word!r} is not an argument, an address and a number "
                                f"({what})")
        address, value = m.groups()
        if address not in FANUC_ARGUMENTS:
            raise _refuse(call, f"{address} is not a macro argument (G, L, N, O and P are "
                                f"not): {what}")
        if any(a == address for a, _ in arguments):
            raise _refuse(call, f"{address} is given twice")
        if _digits(value) > FANUC_MAX_DIGITS:
            raise _refuse(call, f"{word}: more than {FANUC_MAX_DIGITS} digits")
        if address in FANUC_WHOLE and "." in value:
            raise _refuse(call, f"{word}: {address} is a whole number, without a decimal point")
        if address not in FANUC_WHOLE and "." not in value:
            raise _refuse(call, f"{word} without a decimal point is passed in least increments "
                                f"(it could be a thousandth of what you mean): write {word}.")
        arguments.append((address, Decimal(value)))
    return FanucMacro(int(program.group(1)), tuple(arguments))


def parse_sinumerik(call: str) -> SinumerikCall:
    """The cycle or subprogram call in `call`, or PlanError naming what is wrong."""
    cycles = ", ".join(sorted(SINUMERIK_CYCLES))
    what = (f"one measuring cycle with numeric arguments, e.g. "
            f"'CYCLE978(0,1,,1,-10,100,,3,1)' ({cycles}), or a subprogram L<number> "
            f"without arguments")
    text = call.strip()
    if re.fullmatch(r"L[1-9][0-9]{0,6}", text):
        return SinumerikCall(text, None)
    m = re.fullmatch(r"([A-Z0-9_]+)\(([^()]*)\)", text)
    if m is None:
        raise _refuse(call, what)
    name, inside = m.groups()
    if name not in SINUMERIK_CYCLES:
        raise _refuse(call, f"{name} is not a measuring cycle taken here: {what}")
    parts = [p.strip() for p in inside.split(",")] if inside.strip() else []
    if len(parts) > SINUMERIK_MAX_ARGUMENTS:
        raise _refuse(call, f"more than {SINUMERIK_MAX_ARGUMENTS} arguments")
    arguments: list[Decimal | None] = []
    for part in parts:
        if not part:
            arguments.append(None)
            continue
        if re.fullmatch(_NUMBER, part) is None or _digits(part) > SINUMERIK_MAX_DIGITS:
            raise _refuse(call, f"argument {part!r} is not a number of at most "
                                f"{SINUMERIK_MAX_DIGITS} digits (or left empty)")
        arguments.append(Decimal(part))
    return SinumerikCall(name, tuple(arguments))
