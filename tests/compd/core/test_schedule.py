"""The daemon's schedule on a fake clock: hours of cycles in milliseconds.

The clock is a float the test moves: a cycle "takes" what the test says, then
the loop waits until the deadline, exactly as `CycleLoop.run` does with
`time.monotonic`.
"""

from __future__ import annotations

import itertools
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from compd.core.schedule import (
    SHUTDOWN_MARGIN_CYCLES,
    Schedule,
    shutdown_ramp_cycles,
    staggered_starts,
)

#: a monotonic clock's reading after weeks of uptime: where rounding bites
START_S = 2_000_000.123


def _run(schedule: Schedule, durations: list[float]) -> tuple[list[float], list[int]]:
    """Run one cycle per duration; returns each cycle's start and the skips."""
    now = schedule.start_s
    starts: list[float] = []
    skips: list[int] = []
    for took_s in durations:
        starts.append(now)
        now += took_s
        skips.append(schedule.advance(now))
        now += max(0.0, schedule.wait_s(now))  # the loop sleeps until the deadline
    return starts, skips


def test_ten_hours_on_time_do_not_drift() -> None:
    period = 0.1  # not a binary fraction: a summed deadline would drift
    schedule = Schedule(period, START_S)
    n = 360_000  # ten hours of 100 ms cycles
    starts, skips = _run(schedule, [0.02] * n)
    assert not any(skips) and schedule.overruns == 0
    assert schedule.index == n
    assert starts[-1] == pytest.approx(START_S + (n - 1) * period, abs=1e-9)
    summed = START_S
    for _ in range(n):
        summed += period
    # the summed schedule (the old arithmetic) wanders; ours stays on the grid
    assert abs(schedule.deadline_s - (START_S + n * period)) <= 1e-9
    assert abs(summed - (START_S + n * period)) > abs(schedule.deadline_s - (START_S + n * period))


def test_an_overrun_skips_to_the_next_deadline_in_the_future() -> None:
    schedule = Schedule(1.0, START_S)
    assert schedule.advance(START_S + 0.3) == 0  # on time: deadline start + 1
    assert schedule.deadline_s == START_S + 1.0
    skipped = schedule.advance(START_S + 1.0 + 3.5)  # the next cycle took 3.5 periods
    assert skipped == 3 and schedule.overruns == 1
    assert schedule.deadline_s == START_S + 5.0
    assert schedule.wait_s(START_S + 4.5) == pytest.approx(0.5)


def test_ending_exactly_on_the_deadline_is_not_an_overrun() -> None:
    schedule = Schedule(0.5, START_S)
    assert schedule.advance(START_S + 0.5) == 0
    assert schedule.wait_s(START_S + 0.5) == 0.0 and schedule.overruns == 0


def test_after_a_stall_there_is_no_catch_up_burst() -> None:
    period = 0.1
    schedule = Schedule(period, START_S)
    durations = [0.01] * 100 + [5.05] + [0.01] * 100  # one cycle stalls 50.5 periods
    starts, skips = _run(schedule, durations)
    assert skips.count(0) == 200 and skips[100] == 50 and schedule.overruns == 1
    gaps = [b - a for a, b in itertools.pairwise(starts)]
    # the stalled cycle's successor starts on the first deadline after it ...
    assert gaps[100] == pytest.approx(5.1, abs=1e-9)
    # ... and no two cycles ever start closer than one period
    assert min(gaps) == pytest.approx(period, abs=1e-9)


@settings(max_examples=200, deadline=None)
@given(period=st.floats(0.001, 10.0),
       durations=st.lists(st.floats(0.0, 5.0), min_size=1, max_size=300))
def test_deadlines_stay_on_the_grid_and_never_in_the_past(period: float,
                                                          durations: list[float]) -> None:
    schedule = Schedule(period, START_S)
    now = START_S
    for took in durations:
        previous = schedule.index
        now += took * period
        skipped = schedule.advance(now)
        assert schedule.index == previous + 1 + skipped
        assert schedule.deadline_s >= now  # never a deadline already past
        if skipped:
            # ... and the one before it was past: exactly the deadlines missed were skipped
            assert schedule.deadline_s - period <= now + 1e-9 * max(1.0, abs(now))
        now += schedule.wait_s(now)
    # at most one cycle per period, whatever the durations: no burst
    assert len(durations) <= math.floor((now - START_S) / period + 1e-6)


def test_machine_time_runs_at_the_time_scale() -> None:
    schedule = Schedule(0.04, START_S, time_scale=25.0)  # a 1 s machine period, 25x
    assert schedule.machine_s(START_S) == 0.0
    assert schedule.machine_s(START_S + 0.04) == pytest.approx(1.0)
    assert schedule.machine_s(START_S + 144.0) == pytest.approx(3600.0)


def test_the_shutdown_ramp_gets_the_full_scale_ramp_plus_a_margin() -> None:
    # 200 µm at 1 µm/s in 1 s cycles: 200 cycles of ramp
    assert shutdown_ramp_cycles(200.0, 1.0, 1.0) == 200 + SHUTDOWN_MARGIN_CYCLES
    # a ramp that does not fill the last cycle still gets it
    assert shutdown_ramp_cycles(10.0, 3.0, 1.0) == 4 + SHUTDOWN_MARGIN_CYCLES


@pytest.mark.parametrize("period", [0.0, -1.0, math.nan, math.inf])
def test_a_period_that_is_not_positive_is_refused(period: float) -> None:
    with pytest.raises(ValueError, match="period"):
        Schedule(period, START_S)


@pytest.mark.parametrize("n", [1, 2, 7, 64, 100, 500, 1000, 1024])
@pytest.mark.parametrize("period", [0.05, 1.0, 10.0])
def test_staggered_starts_are_spaced_and_spread_the_phases_evenly(n: int,
                                                                   period: float) -> None:
    starts = staggered_starts(n, period, min_spacing_s=0.01)
    assert len(starts) == n and starts[0] == 0.0
    gaps = [b - a for a, b in itertools.pairwise(starts)]
    assert all(g >= 0.01 - 1e-12 for g in gaps)  # never a burst of start-ups
    # every phase k/n of the period taken exactly once: no two deadlines together
    phases = sorted(round((s / period * n) % n) % n for s in starts)
    assert phases == list(range(n))
    # and no slower than it must be: the spacing is the smallest such one
    # (within the next integers coprime with n)
    assert starts[-1] <= (n - 1) * (0.01 + period / n) * 2


def test_staggered_starts_refuse_a_bad_period() -> None:
    assert staggered_starts(0, 1.0) == []
    with pytest.raises(ValueError, match="period"):
        staggered_starts(3, 0.0)
