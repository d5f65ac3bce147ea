"""The program `compd plan` writes: a header that says what it does and why,
the modal state set (again after every call of the user's measuring cycle),
the schedule's blocks (`compd.offline.plan.schedule`) in a
dialect's words (`compd.offline.plan.dialects`), the end.

`time_scale` N > 1 divides every dwell by N (whole milliseconds), for a
simulated machine whose plant and daemon run at N machine seconds per real
second (``[machine] time_scale``): the header says so and gives the real
dwell beside the schedule's. Never on a real machine.

The header states the schedule's time (the dwells of the steps and rests,
exactly the hours asked), the dwell in all (plus each measuring cycle's
spindle run-down) and the axes the program moves: only those named in
``--safe-position`` and ``--probe-at``, none without them.
"""

from __future__ import annotations

import textwrap
from dataclasses import dataclass

from compd.offline.plan.dialects import Dialect, Probing, num
from compd.offline.plan.schedule import Dwell, Experiment, Measure, PlanError, Spin

WIDTH = 66


@dataclass(frozen=True)
class Program:
    text: str
    #: every second the dwells of the program add up to (divided by the time scale)
    dwell_total_ms: int
    axes: tuple[str, ...]


def _hm(ms: int) -> str:
    minutes = round(ms / 60_000)
    return f"{minutes // 60} h {minutes % 60:02d} min"


def _h(ms: int) -> str:
    return f"{ms / 3_600_000:.2f} h"


def axes_moved(probing: Probing | None) -> tuple[str, ...]:
    if probing is None:
        return ()
    named = set(probing.safe) | set(probing.at)
    return tuple(a for a in ("X", "Y", "Z") if a in named)


def _why() -> list[str]:
    return [
        "Why this order: a model only generalises to the regimes its record spanned, "
        "see docs/calibration.md. Each speed is held long enough to heat through and is "
        "reached twice: from below, in a rising staircase from rest, and from above, in a "
        "falling staircase after a rest. The spindle rests twice, so that the record "
        "holds cool-downs from the top and from the bottom speed.",
        "Start with the machine at rest and in equilibrium with its room, after a night "
        "or a weekend.",
    ]


def _measuring_lines(exp: Experiment, dialect: Dialect, probing: Probing | None,
                     recorder: bool) -> list[str]:
    if exp.probe_every_ms is None or probing is None:
        return ["No measuring cycle: record the displacement with sensors at a test "
                "mandrel (ISO 230-3), as a channel of the daemon."]
    lines = [f"Measuring cycle: at the start, the cold reference, every "
             f"{exp.probe_every_ms / 60_000:g} min of the schedule and at its end, "
             f"{exp.measurements} in all. The spindle stops for each one, M5 and "
             f"{num(probing.spindle_stop_s)} s to run down, and restarts at its speed; "
             f"the moves and the probing add their own time."]
    if dialect.name == "linuxcnc":
        lines.append(f"LinuxCNC: G38.2 down in Z from Z{num(probing.at['Z'])} by at most "
                     f"{num(probing.depth_mm)} mm at F{num(probing.feed_mm_min)}; when "
                     f"nothing is touched the error stops the program. The probed Z minus "
                     f"the first one, in um, goes to motion.analog-out-00 by M68 E0, the "
                     f"measurement's number to motion.analog-out-01 by M68 E1: net them to "
                     f"the pins compd reads as the displacement channel and counter.")
    elif probing.call is not None:
        lines.append(f"The measuring cycle is your call {probing.call.block}: it must leave "
                     f"the displacement where compd reads it as a channel, and it moves "
                     f"what it moves. After it the program sets its modal state again, "
                     f"as at the start, before any other block.")
    if recorder:
        lines.append("Record the run with compd run and the recorder settings written "
                     "beside this program, its name with .recorder.toml; then compd fit "
                     "takes the database.")
    return lines


def _scaled(ms: int, time_scale: float) -> int:
    """A dwell of `ms` schedule milliseconds at `time_scale` (at least 1 ms)."""
    return ms if time_scale == 1.0 else max(1, round(ms / time_scale))


def _time_scale_lines(exp: Experiment, time_scale: float, dwell_total_ms: int) -> list[str]:
    if time_scale == 1.0:
        return []
    return [f"TIME SCALE {time_scale:g}: every dwell is divided by {time_scale:g}, "
            f"{dwell_total_ms / 1000:.3f} s of dwell for {_hm(exp.duration_ms)} of "
            f"schedule, for a simulated machine whose plant and daemon run at "
            f"[machine] time_scale = {time_scale:g}. Not for a real machine: its heat "
            f"does not run faster."]


def _header(exp: Experiment, dialect: Dialect, probing: Probing | None, dwell_total_ms: int,
            summary: str, recorder: bool, time_scale: float) -> list[str]:
    axes = axes_moved(probing)
    moves = (f"Axes moved: {', '.join(axes)} only, rapid G0 to the positions named, Z "
             f"first; work coordinates G54, mm." if axes else
             "Axes moved: none, no --safe-position given: the spindle only.")
    if probing is not None and probing.call is not None and exp.probe_every_ms is not None:
        moves += " Your measuring cycle moves what it moves besides."
    paragraphs = [
        f"compd plan: a thermal calibration experiment for compd fit, {dialect.name} "
        f"dialect.",
        summary,
        f"Duration: {_hm(exp.duration_ms)} of spindle steps and rests, "
        f"{exp.duration_ms / 1000:.3f} s of dwell, plus the measuring cycles. "
        f"Dwell in all: {dwell_total_ms / 1000:.3f} s.",
        *(_time_scale_lines(exp, time_scale, dwell_total_ms)),
        moves,
        *(_why()),
        *(_measuring_lines(exp, dialect, probing, recorder)),
        "Schedule:",
    ]
    return wrapped_with_schedule(paragraphs, exp, "rpm")


def wrapped_with_schedule(paragraphs: list[str], exp: Experiment, unit: str) -> list[str]:
    """The header's paragraphs wrapped to WIDTH, then one line a step of the schedule:
    its span, its level in `unit` (spindle rpm, axis percent duty) or rest, its entry."""
    lines: list[str] = []
    for p in paragraphs:
        lines += textwrap.wrap(p, WIDTH, break_on_hyphens=False) or [""]
    for k, step in enumerate(exp.steps, 1):
        what = f"{step.speed_rpm} {unit}" if step.speed_rpm else "rest"
        lines.append(f"  {k:2d}. {_h(step.start_ms)} - {_h(step.start_ms + step.duration_ms)}"
                     f"  {what}, {step.entry}")
    return lines


def make_program(exp: Experiment, dialect: Dialect, probing: Probing | None, *,
                 summary: str, recorder: bool = False,
                 time_scale: float = 1.0) -> Program:
    """The whole program as text (LF line ends, a final newline); every dwell
    divided by `time_scale` (see the module)."""
    if exp.probe_every_ms is not None and (probing is None or "Z" not in probing.safe):
        raise PlanError("the measuring cycle moves the machine: give --safe-position with "
                        "a Z to retract to (e.g. --safe-position Z=100)")
    if probing is not None and probing.safe and "Z" not in probing.safe:
        raise PlanError("--safe-position without Z would move X/Y at whatever height the "
                        "tool is: name Z too")
    body: list[str] = [*dialect.modal, dialect.stop()]
    if probing is not None:
        body += dialect.moves(probing.safe)
    dwell_total = 0
    count = exp.measurements  # a sum over the actions: once, not per cycle
    for action in exp.actions:
        if isinstance(action, Spin):
            body += dialect.spindle(action.speed_rpm)
        elif isinstance(action, Dwell):
            ms = _scaled(action.ms, time_scale)
            body += dialect.dwell(ms)
            dwell_total += ms
        elif isinstance(action, Measure) and probing is not None:  # checked above
            body.append(dialect.comment(f"measuring cycle {action.index + 1} of {count} "
                                        f"at {_h(action.at_ms)}"))
            if action.stops_rpm:
                stop_ms = round(probing.spindle_stop_s * 1000)
                stop_ms = _scaled(stop_ms, time_scale) if stop_ms else 0
                body.append(dialect.stop())
                if stop_ms:
                    body += dialect.dwell(stop_ms)
                    dwell_total += stop_ms
            body += dialect.measuring(action.index, probing)
    body += [dialect.stop(), *dialect.epilogue()]
    header = _header(exp, dialect, probing, dwell_total, summary, recorder, time_scale)
    lines = [*dialect.prologue("compd plan thermal calibration"),
             *(dialect.comment(h) for h in header),
             *body]
    return Program("\n".join(lines) + "\n", dwell_total, axes_moved(probing))
