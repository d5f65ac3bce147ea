"""What an axis costs the pure cycle, counted, not timed: the function calls one
cycle makes (Python's and C's, `sys.setprofile`) with three axes written as value
+ slope and read back, less those of the same cycle without axes, per axis. A
count is the same on an idle and a loaded machine, so the test is deterministic;
`benchmarks/bench_axes_cost.py` measures the time.

Each axis steps its value and slope models, judges both read-backs and its
reference, runs its fault policy, moves two output stages, builds its health view
once (its status word, cause and state from it), its writes and its row: about 95
calls. Building the view, the decision and the rows as frozen dataclasses, the
status word as a `Status` flag (twice), the cause twice, every output name with an
f-string each cycle, and judging a read-back of exactly the value confirmed as any
other took about 177."""

from __future__ import annotations

import sys
from types import FrameType
from typing import Any

from compd.core.cycle import Cycle
from compd.core.validation import ChannelLimits
from compd.testing import FakeClock
from tests.compd.core.cycle_helpers import params, sp2
from tests.compd.core.test_cycle_axes import inputs, x_axis

#: calls per axis and cycle, at most (about 95 now; 177 when each axis built its
#: view, decision and rows as frozen dataclasses and its status word flags twice)
MOST_CALLS_PER_AXIS = 110
WARMUP, CYCLES = 10, 50


def _calls_per_cycle(axes: str) -> float:
    """The calls of one cycle (plan and commit, every axis read back as written),
    averaged over `CYCLES` after `WARMUP`, with an axis for each letter of `axes`."""
    chans = dict(params().channels)
    chans["nut"] = ChannelLimits(-20.0, 150.0, max_rate_per_s=0.5, stale_after_s=30.0)
    cycle = Cycle(params(channels=chans, axes=tuple(x_axis(axis=a) for a in axes),
                         readback=True, axes_status_name="axes_status" if axes else None),
                  sp2())
    clock = FakeClock(period_s=1.0)
    held = dict.fromkeys(("offset", *cycle.axes.names), 0.0)
    count = 0

    def counted(frame: FrameType, event: str, arg: Any) -> None:
        nonlocal count
        if event in ("call", "c_call"):
            count += 1

    try:
        for k in range(WARMUP + CYCLES):
            t = clock.tick()
            if k == WARMUP:
                sys.setprofile(counted)
            plan = cycle.plan(t, inputs(t, nut=21.0 + 0.01 * k), held["offset"],
                              axes_readback={n: held[n] for n in cycle.axes.names} or None)
            row = cycle.commit()
            held.update(plan.writes)
    finally:
        sys.setprofile(None)
    # the axes tracked their models all along: the count is of the cycle's usual path
    assert all(a.in_force for a in row.axes.values()) and len(row.axes) == len(axes)
    return count / CYCLES


def test_an_axis_costs_the_cycle_under_a_hundred_and_ten_calls() -> None:
    per_axis = (_calls_per_cycle("xyz") - _calls_per_cycle("")) / 3
    assert per_axis <= MOST_CALLS_PER_AXIS, f"{per_axis:.1f} calls per axis and cycle"
