"""Each controller's words for the blocks `compd plan` writes.

- LinuxCNC (RS274NGC, `.ngc`): comments ``(text)`` with no parentheses
  inside; safe start ``G21 G90 G17 G40 G80 G94``; dwell ``G4 P`` in seconds,
  no longest (P is a double); the measuring cycle is ``G38.2`` down in Z, its
  result put out by ``M68``; end ``M2``.
- FANUC (0i/30i, ISO code): ``%``, ``O####`` and the program, then ``M30``
  and ``%``; comments ``(TEXT)`` in upper case and ISO characters; safe start
  ``G21 G90 G17 G40 G80 G94``; dwell ``G04 X`` in seconds with a decimal
  point, alone in its block, at most 9999.9999 s with IS-C (99999.999 s with
  IS-B): split at 9999 s; the measuring cycle is the user's macro call
  (``G65 P9810 …``).
- SINUMERIK (840D, native language, `.mpf`): comments ``; text``; safe start
  ``G71 G90 G17 G40 G94`` (G71 is metric; G21 is its ISO dialect); dwell
  ``G4 F`` in seconds, alone in its block, split at 9999 s as for FANUC (the
  manual we read gives no longest); the measuring cycle is the user's cycle
  (``CYCLE978(…)``); end ``M30``.

Every FANUC coordinate and feed carries a decimal point: without one a
control without "calculator type" input reads ``Z100`` as 0.1 mm (IS-B).
A dwell longer than a dialect's longest is split into equal chunks.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from compd.offline.plan.schedule import PlanError


def num(value: float) -> str:
    """A value with a decimal point and at most 3 decimals: 100.0, 12.345, -0.5."""
    text = f"{value:.3f}".rstrip("0")
    text = text + "0" if text.endswith(".") else text
    return "0.0" if text in ("-0.0", "-0") else text


@dataclass(frozen=True)
class Probing:
    """Where and how the measuring cycle runs (positions in mm, work coordinates)."""

    safe: dict[str, float]
    at: dict[str, float] = field(default_factory=dict)
    depth_mm: float = 10.0
    feed_mm_min: float = 100.0
    call: str | None = None
    spindle_stop_s: float = 5.0


def _moves(position: dict[str, float], g0: str) -> list[str]:
    """Z first (up, away from the work on a mill), then X and Y together."""
    blocks = []
    if "Z" in position:
        blocks.append(f"{g0} Z{num(position['Z'])}")
    plane = " ".join(f"{a}{num(position[a])}" for a in ("X", "Y") if a in position)
    if plane:
        blocks.append(f"{g0} {plane}")
    return blocks


class Dialect:
    """The words shared by the three; each subclass says what differs."""

    name = ""
    suffix = ".nc"
    g0 = "G0"
    max_dwell_ms: int | None = None
    safe_start = ""

    def comment(self, text: str) -> str:
        raise NotImplementedError

    def prologue(self, title: str) -> list[str]:
        return []

    def epilogue(self) -> list[str]:
        return ["M2"]

    def dwell_block(self, seconds: str) -> str:
        raise NotImplementedError

    def spindle(self, rpm: int) -> list[str]:
        return [f"S{rpm} M3"] if rpm else ["M5"]

    def stop(self) -> str:
        return "M5"

    def dwell(self, ms: int) -> list[str]:
        """One block, or equal chunks of at most `max_dwell_ms` summing to `ms`."""
        limit = self.max_dwell_ms
        parts = 1 if limit is None else -(-ms // limit)
        base, extra = divmod(ms, parts)
        return [self.dwell_block(num((base + (1 if k < extra else 0)) / 1000))
                for k in range(parts)]

    def moves(self, position: dict[str, float]) -> list[str]:
        return _moves(position, self.g0)

    def measuring(self, index: int, probing: Probing) -> list[str]:
        """The measuring cycle's blocks from the safe position back to it."""
        blocks = self.moves({a: v for a, v in probing.at.items() if a != "Z"})
        if "Z" in probing.at:
            blocks += self.moves({"Z": probing.at["Z"]})
        blocks += self.measure(index, probing)
        blocks += self.moves({"Z": probing.safe["Z"]})
        blocks += self.moves({a: v for a, v in probing.safe.items() if a != "Z"})
        return blocks

    def measure(self, index: int, probing: Probing) -> list[str]:
        if probing.call is None:
            raise PlanError(f"{self.name}: the measuring cycle needs --probe-call")
        return [probing.call]

    def check_call(self, call: str) -> str:
        return call


class LinuxCNC(Dialect):
    """LinuxCNC's RS274NGC: ``G38.2`` from ``--probe-at`` down by the depth; the
    probed Z relative to the first measurement, in µm, on ``motion.analog-out-00``
    (``M68 E0``) and the measurement's number on ``motion.analog-out-01`` (``M68 E1``)."""

    name = "linuxcnc"
    suffix = ".ngc"
    safe_start = "G21 G90 G17 G40 G80 G94"

    def comment(self, text: str) -> str:
        return f"({text.replace('(', '[').replace(')', ']')})"

    def dwell_block(self, seconds: str) -> str:
        return f"G4 P{seconds}"

    def measure(self, index: int, probing: Probing) -> list[str]:
        if "Z" not in probing.at:
            raise PlanError("linuxcnc: the measuring cycle probes down in Z from --probe-at: "
                            "give its Z (e.g. --probe-at X=100,Y=50,Z=20)")
        target = probing.at["Z"] - probing.depth_mm
        blocks = [f"G38.2 Z{num(target)} F{num(probing.feed_mm_min)}"]
        if index == 0:
            blocks.append("#<_compd_z0> = #5063")
        blocks += ["M68 E0 Q[[#5063 - #<_compd_z0>] * 1000]", f"M68 E1 Q{index + 1}",
                   f"G0 Z{num(probing.at['Z'])}"]
        return blocks

    def check_call(self, call: str) -> str:
        raise PlanError("linuxcnc probes with G38.2 from --probe-at; --probe-call is for "
                        "the fanuc and sinumerik dialects")


#: FANUC comment characters (ISO code): upper case, digits and a few signs; never
#: parentheses (the comment's own), % (end of record) or ; (end of block on screen)
_FANUC_COMMENT = re.compile(r"[^A-Z0-9 .,+\-/*=:#\[\]'?&]")
#: addresses whose value is a whole number (codes, speed, program number, dwell in ms)
_FANUC_INTEGER = frozenset("GMSPNOTHDL")
_FANUC_CALL = re.compile(r"[A-Z][+-]?(?:\d+\.?\d*|\.\d+)(?: *[A-Z][+-]?(?:\d+\.?\d*|\.\d+))*")


class Fanuc(Dialect):
    name = "fanuc"
    suffix = ".nc"
    g0 = "G00"
    max_dwell_ms = 9_999_000
    safe_start = "G21 G90 G17 G40 G80 G94"

    def __init__(self, program_number: int = 1000) -> None:
        self.program_number = program_number

    def comment(self, text: str) -> str:
        text = text.upper().replace("(", "[").replace(")", "]").replace(";", ",")
        return f"({_FANUC_COMMENT.sub(' ', text)})"

    def prologue(self, title: str) -> list[str]:
        return ["%", f"O{self.program_number:04d} {self.comment(title)}"]

    def epilogue(self) -> list[str]:
        return ["M30", "%"]

    def dwell_block(self, seconds: str) -> str:
        return f"G04 X{seconds}"

    def spindle(self, rpm: int) -> list[str]:
        return [f"S{rpm} M03"] if rpm else ["M05"]

    def stop(self) -> str:
        return "M05"

    def check_call(self, call: str) -> str:
        call = call.strip()
        if not _FANUC_CALL.fullmatch(call):
            raise PlanError(f"--probe-call {call!r}: a FANUC block of words, an upper-case "
                            f"address and a number each (e.g. 'G65 P9810 Z-10. F500.')")
        for address, value in re.findall(r"([A-Z])([+-]?[\d.]+)", call):
            if address not in _FANUC_INTEGER and "." not in value:
                raise PlanError(f"--probe-call {call!r}: {address}{value} without a decimal "
                                f"point is read in least increments ({address}{value} "
                                f"could be a thousandth of what you mean): write "
                                f"{address}{value}.")
        return call


_SINUMERIK_CALL = re.compile(r"[A-Za-z_][A-Za-z0-9_]{0,31}(?:\([ -:<-~]*\))?")


class Sinumerik(Dialect):
    name = "sinumerik"
    suffix = ".mpf"
    max_dwell_ms = 9_999_000
    safe_start = "G71 G90 G17 G40 G94"

    def comment(self, text: str) -> str:
        return f"; {text}"

    def epilogue(self) -> list[str]:
        return ["M30"]

    def dwell_block(self, seconds: str) -> str:
        return f"G4 F{seconds}"

    def check_call(self, call: str) -> str:
        call = call.strip()
        if not _SINUMERIK_CALL.fullmatch(call):
            raise PlanError(f"--probe-call {call!r}: a SINUMERIK cycle or subprogram name, "
                            f"with its arguments in parentheses if any (e.g. "
                            f"'CYCLE978(0,1,,1,-10,100,,3,1)'), no ';'")
        return call


def dialect(name: str, *, program_number: int = 1000) -> Dialect:
    if name == "linuxcnc":
        return LinuxCNC()
    if name == "fanuc":
        return Fanuc(program_number)
    if name == "sinumerik":
        return Sinumerik()
    raise PlanError(f"unknown dialect {name!r}")


DIALECTS = ("linuxcnc", "fanuc", "sinumerik")
