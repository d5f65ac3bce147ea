"""An axis written as one offset at its read position, started without a checkpoint
of that offset (none, or one of the line's parameters alone): the offset the
controller holds is read back as applied where the axis is now, so a line it holds
is confirmed, not taken for a value off by the slope's part; while no position has
been read the read-back is not judged and the axis writes nothing."""

from __future__ import annotations

import math

import pytest

from compd.core.cycle import Cycle
from compd.core.events import EventName
from compd.core.plan import Plan
from compd.testing import FakeClock
from tests.compd.core.cycle_helpers import sp2
from tests.compd.core.test_cycle_axes_position import WALL0, at, line, positional

#: the checkpoint of the axis's line alone (value 10 µm, slope 12 µm/m at 25 mm):
#: what the models ask at steady state, so a line confirmed needs no ramp
LINE_ONLY = {"x": {"value": 10.0, "slope": 12.0, "fresh": False}}


def _mismatch(plan: Plan) -> bool:
    return any(e.name is EventName.READBACK_MISMATCH and e.fields.get("axis") == "x"
               for e in plan.events)


def test_the_offset_read_back_at_start_is_taken_at_the_present_position() -> None:
    cycle = Cycle(positional(readback=True, value_slew_um_s=1.0), sp2(),
                  axes_state=LINE_ONLY)
    clock = FakeClock(period_s=1.0)
    t = clock.tick()
    # the controller holds the line at 800 mm, where the axis is
    plan = cycle.plan(t, at(t, 800.0), 0.0, wall_s=WALL0 + t,
                      axes_readback={"x_comp_offset": line(800.0)})
    row = cycle.commit()
    assert not _mismatch(plan)
    assert row.axes["x"].value.confirmed == pytest.approx(10.0)
    # no jump: the line it holds, written again (taken at the reference position it
    # was a value of 19.3 µm, and 28.6 µm would be written at 800 mm, less 1 µm/s)
    assert plan.writes["x_comp_offset"] == pytest.approx(line(800.0))


def test_without_a_position_the_axis_holds_until_one_is_read() -> None:
    cycle = Cycle(positional(readback=True, value_slew_um_s=1.0), sp2(),
                  axes_state=LINE_ONLY)
    clock = FakeClock(period_s=1.0)
    for _ in range(3):  # the position is not a number: nowhere to read the offset at
        t = clock.tick()
        plan = cycle.plan(t, at(t, math.nan), 0.0, wall_s=WALL0 + t,
                          axes_readback={"x_comp_offset": line(800.0)})
        cycle.commit()
        assert not _mismatch(plan) and "x_comp_offset" not in plan.writes
    t = clock.tick()
    plan = cycle.plan(t, at(t, 800.0), 0.0, wall_s=WALL0 + t,
                      axes_readback={"x_comp_offset": line(800.0)})
    row = cycle.commit()
    assert not _mismatch(plan)
    assert row.axes["x"].value.confirmed == pytest.approx(10.0)
    assert plan.writes["x_comp_offset"] == pytest.approx(line(800.0))


def test_without_a_checkpoint_the_offset_held_is_the_start() -> None:
    # nothing known of the line: the offset the controller holds is the value at the
    # present position, the slope starts at 0, both ramp at their rates (no jump)
    cycle = Cycle(positional(readback=True, value_slew_um_s=1.0, slope_slew_um_m_s=1.0),
                  sp2())
    clock = FakeClock(period_s=1.0)
    t = clock.tick()
    plan = cycle.plan(t, at(t, 800.0), 0.0, wall_s=WALL0 + t,
                      axes_readback={"x_comp_offset": 5.0})
    cycle.commit()
    # one second: the value 1 µm up, the slope 1 µm/m, 775 mm from the reference
    assert plan.writes["x_comp_offset"] == pytest.approx(5.0 + 1.0 + 0.775)
