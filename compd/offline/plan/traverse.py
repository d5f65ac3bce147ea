"""The traverse experiment of a position-dependent calibration (`compd plan
--traverse AXIS --positions …`): the axis's own motion is the heat source, and
the displacement is measured at standstill at each of the positions named.

The schedule is the spindle experiment's (`compd.offline.plan.schedule.design`),
with axis duty levels in place of spindle speeds: each duty held rising, a
rest, each held falling, a rest; a measuring pass at the start (the cold
reference), every ``probe_every_min`` minutes of the schedule and at its end.
The spindle stays stopped throughout, so that the record holds the axis's heat
alone (the nut and the screw's bearings heat the screw, whose growth is the
slope).

One traverse cycle at duty d: a feed move from the lowest position named to the
highest and back (the stroke, at ``feed_mm_min``), then a dwell, so that the
moves take the share d of the cycle:

    moving_ms = 2 · stroke_mm / feed_mm_min · 60,000
    dwell_ms  = moving_ms · (1 - d) / d

A duty step of `hold_ms` runs whole cycles and dwells the remainder, so the
program's time is the schedule's (the moves timed at the programmed feed; a
machine's acceleration makes them a little longer). Worked example: positions
0 … 1000 mm at 10,000 mm/min move 12 s per cycle; at 25 % each cycle dwells
36 s, a cycle every 48 s.

A measuring pass visits every position in rising order by rapid moves and stands
still at each for ``stop_s`` (a laser interferometer's or a ballbar's reading
at standstill), with the user's measuring cycle called there when one is given
(`compd.offline.plan.calls`; the modal state set again after it, and Z back to
the safe position before the axis moves on).

Everything a block holds comes from parsed numbers: axis letters from a fixed
set, positions and feeds through `num`, comments through `plain`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from compd.offline.plan.dialects import Dialect, num
from compd.offline.plan.program import Program, _h, _hm, wrapped_with_schedule
from compd.offline.plan.schedule import (
    MIN_STEP_WARN_MS,
    Dwell,
    Experiment,
    Measure,
    PlanError,
    Spin,
    design,
)

AXES = ("X", "Y", "Z")
#: a program past this many blocks is refused (a controller's memory, a DNC feed)
MAX_BLOCKS = 200_000
#: the feed move in each dialect's words
_G1 = {"linuxcnc": "G1", "fanuc": "G01", "sinumerik": "G1"}


@dataclass(frozen=True)
class Traverse:
    """What the traverse experiment moves and where it measures (mm, mm/min, s)."""

    axis: str
    positions_mm: tuple[float, ...]
    feed_mm_min: float
    stop_s: float
    #: the safe position (work coordinates G54): Z first, then the others
    safe: dict[str, float]

    @property
    def stroke_mm(self) -> float:
        return max(self.positions_mm) - min(self.positions_mm)

    @property
    def moving_ms(self) -> int:
        """One cycle's two feed moves, at the programmed feed."""
        return round(2.0 * self.stroke_mm / self.feed_mm_min * 60_000.0)


def cycle_ms(traverse: Traverse, duty_pct: int) -> int:
    """The length of one traverse cycle at `duty_pct` (moves plus dwell)."""
    return round(traverse.moving_ms * 100 / duty_pct)


def traverse_design(hours: float, duties_pct: Sequence[int], *, rest_h: float | None,
                    probe_every_min: float) -> tuple[Experiment, tuple[str, ...]]:
    """The schedule (`design`, duties in percent in place of speeds) and the
    warnings about it in the traverse's words; PlanError when the rests leave
    no time for the duty steps."""
    n = len(duties_pct)
    total_ms = round(hours * 3_600_000)
    rest_ms = total_ms // (2 * n + 2) if rest_h is None else round(rest_h * 3_600_000)
    if (total_ms - 2 * rest_ms) // (2 * n) < 1000:
        raise PlanError(f"{hours:g} h leave no time for the {2 * n} duty steps after two "
                        f"rests of {rest_ms / 3_600_000:g} h; give more --hours, a shorter "
                        f"--rest-h or fewer --duties")
    exp = design(hours, list(duties_pct), rest_h=rest_h, probe_every_min=probe_every_min)
    warnings = []
    if exp.hold_ms < MIN_STEP_WARN_MS:
        warnings.append(f"each duty is held {exp.hold_ms / 60_000:g} min: a ball screw "
                        f"heats through in hours, so the record will not reach steady states")
    every_ms = exp.probe_every_ms or 0
    if every_ms > exp.hold_ms:
        warnings.append(f"a measuring pass every {every_ms / 60_000:g} min is sparser than "
                        f"the steps ({exp.hold_ms / 60_000:g} min): some steps go unmeasured")
    return exp, tuple(warnings)


def _traverse_blocks(dialect: Dialect, t: Traverse, duty_pct: int, ms: int
                     ) -> tuple[list[str], int]:
    """`ms` of the schedule at `duty_pct`: whole cycles, then a dwell of the rest
    (a duty of 0: a dwell alone). Returns the blocks and the dwell they hold."""
    if duty_pct == 0 or t.moving_ms == 0:
        return dialect.dwell(ms), ms
    period = cycle_ms(t, duty_pct)
    cycles = ms // period
    pause = period - t.moving_ms
    lo, hi = num(min(t.positions_mm)), num(max(t.positions_mm))
    g1 = _G1[dialect.name]
    blocks: list[str] = []
    dwelt = 0
    if cycles:
        blocks.append(dialect.comment(f"{cycles} traverse cycles at {duty_pct} percent duty"))
    for k in range(cycles):
        blocks.append(f"{g1} {t.axis}{hi} F{num(t.feed_mm_min)}" if k == 0 else
                      f"{g1} {t.axis}{hi}")
        blocks.append(f"{g1} {t.axis}{lo}")
        if pause:
            blocks += dialect.dwell(pause)
            dwelt += pause
    rest = ms - cycles * period
    if rest:
        blocks += dialect.dwell(rest)
        dwelt += rest
    return blocks, dwelt


def _pass_blocks(dialect: Dialect, t: Traverse, index: int, count: int, at_ms: int,
                 call_modal: list[str]) -> tuple[list[str], int]:
    """One measuring pass: every position in rising order, a standstill at each."""
    blocks = [dialect.comment(f"measuring pass {index + 1} of {count} at {_h(at_ms)}")]
    stop_ms = round(t.stop_s * 1000)
    dwelt = 0
    retract = dialect.moves({"Z": t.safe["Z"]}) if call_modal and t.axis != "Z" else []
    for x in sorted(t.positions_mm):
        blocks += dialect.moves({t.axis: x})
        blocks += call_modal + retract  # the user's cycle may leave Z anywhere
        if stop_ms:
            blocks += dialect.dwell(stop_ms)
            dwelt += stop_ms
    return blocks, dwelt


def _header(exp: Experiment, dialect: Dialect, t: Traverse, summary: str,
            dwell_total_ms: int, has_call: bool) -> list[str]:
    positions = ", ".join(num(x) for x in sorted(t.positions_mm))
    others = [a for a in AXES if a in t.safe and a not in (t.axis, "Z")]
    paragraphs = [
        f"compd plan: a traverse experiment for a position-dependent calibration of "
        f"the {t.axis} axis, {dialect.name} dialect.",
        summary,
        f"Duration: {_hm(exp.duration_ms)} of duty steps and rests plus the measuring "
        f"passes. Dwell in all: {dwell_total_ms / 1000:.3f} s.",
        f"Heat: {t.axis} traverses {num(min(t.positions_mm))} - "
        f"{num(max(t.positions_mm))} mm and back at F{num(t.feed_mm_min)} mm/min, "
        f"{t.moving_ms / 1000:g} s of motion a cycle, then a dwell, so that the moves "
        f"take the duty's share of the time. The spindle stays stopped.",
        f"Axes moved: Z first to the safe position, "
        f"{', '.join(others) if others else 'no other'} to it, then {t.axis} only; "
        f"work coordinates G54, mm."
        + (" Your measuring cycle moves what it moves besides." if has_call else ""),
        f"Measuring pass: at the start, the cold reference, every "
        f"{(exp.probe_every_ms or 0) / 60_000:g} min of the schedule and at its end, "
        f"{exp.measurements} in all; each stops at {t.axis} = {positions} mm in that "
        f"order for {num(t.stop_s)} s"
        + (", calling your measuring cycle there" if has_call else
           " (a laser interferometer or ballbar reading at standstill)") + ".",
        "Record the displacement of each pass at each position, one row per pass and "
        "one column per position beside the temperatures, named as docs/calibration.md "
        "says; compd fit --positions fits the value and the slope from it.",
        "Start with the machine at rest and in equilibrium with its room.",
        "Schedule:",
    ]
    return wrapped_with_schedule(paragraphs, exp, "percent duty")


def make_traverse_program(exp: Experiment, dialect: Dialect, t: Traverse, *,
                          summary: str, call_block: str | None = None) -> Program:
    """The traverse experiment as a program (LF line ends, a final newline);
    PlanError when it has no safe Z or would pass `MAX_BLOCKS`."""
    if t.axis not in AXES:
        raise PlanError(f"the traverse axis is one of {', '.join(AXES)}, not {t.axis!r}")
    if "Z" not in t.safe:
        raise PlanError("the traverse moves the machine: give --safe-position with a Z to "
                        "retract to first (e.g. --safe-position Z=100)")
    if len(set(t.positions_mm)) < 2:
        raise PlanError("the traverse needs two or more distinct --positions")
    call_modal = [] if call_block is None else [call_block, *dialect.modal]
    body: list[str] = [*dialect.modal, dialect.stop(), *dialect.moves(t.safe)]
    dwell_total = 0
    duty = 0
    count = exp.measurements
    for action in exp.actions:
        if isinstance(action, Spin):  # a duty level in percent, in the spindle's place
            duty = action.speed_rpm
        elif isinstance(action, Dwell):
            blocks, dwelt = _traverse_blocks(dialect, t, duty, action.ms)
            body += blocks
            dwell_total += dwelt
        elif isinstance(action, Measure):
            blocks, dwelt = _pass_blocks(dialect, t, action.index, count, action.at_ms,
                                         call_modal)
            body += blocks
            dwell_total += dwelt
        if len(body) > MAX_BLOCKS:
            raise PlanError(f"the program would pass {MAX_BLOCKS} blocks: the traverse "
                            f"cycle is {t.moving_ms / 1000:g} s; give a longer stroke, a "
                            f"slower --feed or fewer --hours")
    body += [*dialect.moves({"Z": t.safe["Z"]}), *dialect.epilogue()]
    header = _header(exp, dialect, t, summary, dwell_total, call_block is not None)
    lines = [*dialect.prologue("compd plan traverse calibration"),
             *(dialect.comment(h) for h in header), *body]
    axes = tuple(a for a in AXES if a in t.safe or a == t.axis)
    return Program("\n".join(lines) + "\n", dwell_total, axes)
