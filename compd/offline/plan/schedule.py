"""The calibration experiment `compd plan` writes, as a timeline: which spindle
speed when, for how long, and when the measuring cycle runs. No G-code here
(`compd.offline.plan.dialects` says it in each controller's words).

The design, from what the calibration work found (docs/calibration.md §7 and
the real record in tests/data/fl_thermal): a model only generalises to the
regimes its record spanned, and the record that generalised held each speed
for hours with rests between. So, for the speeds s1 < … < sn:

    s1, s2, …, sn   (a rising staircase, each step held `hold`)
    rest            (the spindle stopped: falling from the top to zero)
    sn, …, s2, s1   (back from rest straight to the top, then a falling staircase)
    rest            (the final cool-down from the lowest speed)

Every speed is held twice, once reached from below and once from above; the
record has rising steps from rest and between speeds, falling steps between
speeds and to rest, from the top and from the bottom. With n speeds there are
2n steps of `hold` and 2 rests of `rest`: `hold = (H - 2·rest) / 2n`, and
without ``rest_h`` each rest is as long as a step (`hold = H / (2n + 2)`; 24 h
and three speeds: 3 h each, the real record held 4 h).

All times are whole milliseconds, so the dwells written sum to the hours
asked exactly (the last rest takes the remainder of the division). The
measuring cycle runs at 0 (the reference, cold), every ``probe_every_min``
minutes of the schedule and at its end; each one stops a turning spindle for
``spindle_stop_s`` (a touch probe or a tool setter needs it still), which the
program adds to the schedule's time.

Worked example: ``design(2.0, [1250, 5000, 2500])`` holds 1250, 2500, 5000 rpm,
rests, 5000, 2500, 1250 rpm and rests, each 900 000 ms (15 min).
"""

from __future__ import annotations

import collections
from dataclasses import dataclass

#: a step held shorter than this cannot reach the thermal steady state of a
#: machine tool (hours); the plan is written, with a warning
MIN_STEP_WARN_MS = 3_600_000


class PlanError(ValueError):
    """The experiment asked for cannot be built (one line, said to the user)."""


@dataclass(frozen=True)
class Step:
    """One segment of the schedule: a speed (0: at rest) from `start_ms` on."""

    speed_rpm: int
    start_ms: int
    duration_ms: int
    #: how the record enters it: "rising from rest", "rising", "falling", "falling to rest"
    entry: str


@dataclass(frozen=True)
class Spin:
    """Start (or change) the spindle, clockwise."""

    speed_rpm: int


@dataclass(frozen=True)
class Dwell:
    """Wait, the spindle as it is. `ms` is one segment of the schedule."""

    ms: int


@dataclass(frozen=True)
class Measure:
    """The measuring cycle, number `index` (0: the reference), `at_ms` into the
    schedule; `stops_rpm`: the speed the spindle turns at, stopped first (0: at
    rest). A `Spin` after it restarts the spindle where the schedule wants it."""

    index: int
    at_ms: int
    stops_rpm: int


Action = Spin | Dwell | Measure


@dataclass(frozen=True)
class Experiment:
    steps: tuple[Step, ...]
    hold_ms: int
    rest_ms: int
    probe_every_ms: int | None
    actions: tuple[Action, ...]
    warnings: tuple[str, ...]

    @property
    def duration_ms(self) -> int:
        return sum(s.duration_ms for s in self.steps)

    @property
    def measurements(self) -> int:
        return sum(isinstance(a, Measure) for a in self.actions)


def _steps(speeds: list[int], hold_ms: int, rest_ms: int, total_ms: int) -> list[Step]:
    up = sorted(speeds)
    plan: list[tuple[int, int]] = [(s, hold_ms) for s in up] + [(0, rest_ms)]
    plan += [(s, hold_ms) for s in reversed(up)]
    plan.append((0, total_ms - sum(d for _, d in plan)))  # the remainder: exact total
    steps: list[Step] = []
    t, previous = 0, 0
    for speed, duration in plan:
        if speed == 0:
            entry = "falling to rest"
        elif previous == 0:
            entry = "rising from rest"
        else:
            entry = "rising" if speed > previous else "falling"
        steps.append(Step(speed, t, duration, entry))
        t, previous = t + duration, speed
    return steps


def _probe_times(total_ms: int, every_ms: int | None) -> list[int]:
    if every_ms is None:
        return []
    times = list(range(0, total_ms, every_ms))
    return [*times, total_ms]


def _actions(steps: list[Step], probes: list[int]) -> list[Action]:
    """The schedule as actions: each step's spindle, its dwell cut where a
    measuring cycle falls; a cycle at a step's boundary runs before the new speed."""
    actions: list[Action] = []
    pending = collections.deque(probes)
    turning = count = 0

    def measure() -> None:
        nonlocal turning, count
        actions.append(Measure(count, pending.popleft(), turning))
        turning, count = 0, count + 1

    for step in steps:
        end = step.start_ms + step.duration_ms
        t = step.start_ms
        while pending and pending[0] <= t:  # at the boundary: measured, then the new speed
            measure()
        if step.speed_rpm != turning:
            actions.append(Spin(step.speed_rpm))
            turning = step.speed_rpm
        while pending and pending[0] < end:
            at = pending[0]
            actions.append(Dwell(at - t))
            measure()
            if step.speed_rpm:
                actions.append(Spin(step.speed_rpm))
                turning = step.speed_rpm
            t = at
        actions.append(Dwell(end - t))
    while pending:  # the final measurement, at rest
        measure()
    return [a for a in actions if not isinstance(a, Dwell) or a.ms > 0]


def design(hours: float, speeds: list[int], *, rest_h: float | None = None,
           probe_every_min: float | None = None) -> Experiment:
    """The experiment for `hours` of schedule over `speeds` (rpm, distinct);
    PlanError when the rests leave no time for the steps."""
    if not speeds:
        raise PlanError("no spindle speed given")
    if len(set(speeds)) != len(speeds):
        raise PlanError("a speed is given twice")
    total_ms = round(hours * 3_600_000)
    n = len(speeds)
    if rest_h is None:
        hold_ms = total_ms // (2 * n + 2)
        rest_ms = hold_ms
    else:
        rest_ms = round(rest_h * 3_600_000)
        hold_ms = (total_ms - 2 * rest_ms) // (2 * n)
    if hold_ms < 1000:
        raise PlanError(f"{hours:g} h leave {hold_ms / 1000:g} s for each of the {2 * n} "
                        f"speed steps after two rests of {rest_ms / 3_600_000:g} h; give "
                        f"more --hours, a shorter --rest-h or fewer --speeds")
    every_ms = None if probe_every_min is None else round(probe_every_min * 60_000)
    steps = _steps(speeds, hold_ms, rest_ms, total_ms)
    actions = _actions(steps, _probe_times(total_ms, every_ms))
    warnings = []
    if hold_ms < MIN_STEP_WARN_MS:
        warnings.append(f"each speed is held {hold_ms / 60_000:g} min: a machine tool's "
                        f"thermal time constants are hours, so the record will not reach "
                        f"steady states (the real record held each speed 4 h)")
    if every_ms is not None and every_ms > hold_ms:
        warnings.append(f"a measuring cycle every {every_ms / 60_000:g} min is sparser than "
                        f"the steps ({hold_ms / 60_000:g} min): some steps go unmeasured")
    return Experiment(tuple(steps), hold_ms, rest_ms, every_ms, tuple(actions),
                      tuple(warnings))
