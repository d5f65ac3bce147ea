"""Each controller's words for the blocks `compd plan` writes.

- LinuxCNC (RS274NGC, `.ngc`): comments ``(text)`` with no parentheses
  inside; modal state ``G17 G21 G40 G80 G90 G94 G97 G8`` and ``G54``; dwell
  ``G4 P`` in seconds, no longest (P is a double); the measuring cycle is
  ``G38.2`` down in Z, its result put out by ``M68``; end ``M2``.
- FANUC (0i/30i machining centres, M series G codes, ISO code): ``%``,
  ``O####`` and the program, then ``M30`` and ``%``; comments ``(TEXT)`` in
  upper case and ISO characters; modal state ``G21`` alone (FANUC wants
  inch/metric in a block of its own), ``G15 G17 G40 G50 G69``, ``G67 G80 G90
  G94 G97`` (at most five G codes a block) and ``G54``; dwell ``G04 X`` in
  seconds with a decimal point, alone in its block, at most 9999.9999 s with
  IS-C (99999.999 s with IS-B): split at 9999 s; the measuring cycle is the
  user's macro call (``G65 P9810 …``).
- SINUMERIK (840D, native language, `.mpf`): comments ``; text``; modal
  state ``G17 G40 G71 G90 G94`` (G71 is metric, G21 its ISO dialect; G94 is
  in the group of G96, so it also ends a constant cutting rate) and ``G54``;
  dwell ``G4 F`` in seconds, alone in its block, split at 9999 s as for
  FANUC (the manual we read gives no longest); the measuring cycle is the
  user's cycle (``CYCLE978(…)``); end ``M30``.

The modal state is never assumed: the blocks that set it open the program
and follow every call of the user's cycle, whose macro may leave G91, G20,
another work offset, a constant surface speed or a modal macro call behind.
With G97 (G94 on SINUMERIK) an ``S`` word is rpm, bounded by `compd plan`'s
own check and the machine's limit; no clamp word is written (FANUC's mill
has none apart from ``G92 S``, which also sets the coordinate system;
SINUMERIK's ``LIMS`` works only under G96/G961/G97 and ``G26`` stays in its
setting data after the program).

Every FANUC coordinate and feed carries a decimal point: without one a
control without "calculator type" input reads ``Z100`` as 0.1 mm (IS-B).
A dwell longer than a dialect's longest is split into equal chunks.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from compd.offline.plan.calls import ProbeCall, parse_fanuc, parse_sinumerik
from compd.offline.plan.comments import plain
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
    call: ProbeCall | None = None
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
    #: the blocks that set every modal group the program relies on
    modal: tuple[str, ...] = ()

    def comment(self, text: str) -> str:
        raise NotImplementedError

    def parse_call(self, call: str) -> ProbeCall:
        """`--probe-call` as a value, or PlanError (one line)."""
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
        """The user's call, written from its parsed value, and the modal state
        set again after it: the next block is a rapid move."""
        if probing.call is None:
            raise PlanError(f"{self.name}: the measuring cycle needs --probe-call")
        return [probing.call.block, *self.modal]


class LinuxCNC(Dialect):
    """LinuxCNC's RS274NGC: ``G38.2`` from ``--probe-at`` down by the depth; the
    probed Z relative to the first measurement, in µm, on ``motion.analog-out-00``
    (``M68 E0``) and the measurement's number on ``motion.analog-out-01`` (``M68 E1``)."""

    name = "linuxcnc"
    suffix = ".ngc"
    modal = ("G17 G21 G40 G80 G90 G94 G97 G8", "G54")

    def comment(self, text: str) -> str:
        return f"({plain(text)})"

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

    def parse_call(self, call: str) -> ProbeCall:
        raise PlanError("linuxcnc probes with G38.2 from --probe-at; --probe-call is for "
                        "the fanuc and sinumerik dialects")


class Fanuc(Dialect):
    name = "fanuc"
    suffix = ".nc"
    g0 = "G00"
    max_dwell_ms = 9_999_000
    modal = ("G21", "G15 G17 G40 G50 G69", "G67 G80 G90 G94 G97", "G54")

    def __init__(self, program_number: int = 1000) -> None:
        self.program_number = program_number

    def comment(self, text: str) -> str:
        return f"({plain(text.upper())})"  # a memory card drops lower case

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

    def parse_call(self, call: str) -> ProbeCall:
        return parse_fanuc(call, self.program_number)


class Sinumerik(Dialect):
    name = "sinumerik"
    suffix = ".mpf"
    max_dwell_ms = 9_999_000
    modal = ("G17 G40 G71 G90 G94", "G54")

    def comment(self, text: str) -> str:
        return f"; {plain(text)}"

    def epilogue(self) -> list[str]:
        return ["M30"]

    def dwell_block(self, seconds: str) -> str:
        return f"G4 F{seconds}"

    def parse_call(self, call: str) -> ProbeCall:
        return parse_sinumerik(call)


def dialect(name: str, *, program_number: int = 1000) -> Dialect:
    if name == "linuxcnc":
        return LinuxCNC()
    if name == "fanuc":
        return Fanuc(program_number)
    if name == "sinumerik":
        return Sinumerik()
    raise PlanError(f"unknown dialect {name!r}")


DIALECTS = ("linuxcnc", "fanuc", "sinumerik")
