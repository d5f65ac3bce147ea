"""An axis written as one offset at its position in the pure cycle (`compd.core.axes`):
the position's age bounds what is written (a position older than its channel's
``stale_after_s`` holds the axis at its last offset), and the offset's read-back is
judged as the value's (a restarted controller at 0 is ramped from at the value's rate,
the slope's part at the present position following at once)."""

from __future__ import annotations

from typing import Any

import pytest

from compd.core.cycle import Cycle
from compd.core.events import EventName
from compd.core.health import Cause
from compd.core.validation import ChannelLimits
from compd.testing import FakeClock
from drivers.base import Sample
from tests.compd.core.cycle_helpers import params, sp2
from tests.compd.core.test_cycle_axes import inputs, x_axis

#: the wall clock at machine time 0 (the temperatures are stamped on it: `inputs`)
WALL0 = 0.0
#: reference 25 mm; value 2·5 = 10 µm, slope 3·5 = 15 µm/m, clamped to 12 µm/m
REF_MM = 25.0


def positional(readback: bool = False, rapid_mm_s: float | None = None, **over: Any) -> Any:
    chans = dict(params().channels)
    chans["nut"] = ChannelLimits(-20.0, 150.0, max_rate_per_s=0.5, stale_after_s=30.0)
    chans["x_pos"] = ChannelLimits(-10.0, 1010.0, max_rate_per_s=rapid_mm_s,
                                   stale_after_s=5.0)
    rates: dict[str, Any] = {"value_slew_um_s": 100.0, "slope_slew_um_m_s": 100.0, **over}
    axis = x_axis(position="x_pos", offset_limit_um=50.0 + 12.0 * 1.035, **rates)
    return params(channels=chans, axes=(axis,), readback=readback)


def at(t: float, x: float, stamped: float | None = None) -> dict[str, Sample]:
    """The temperatures at `t` and the position `x`, stamped `stamped` (the source's
    clock; default: read now)."""
    return {**inputs(t), "x_pos": Sample(x, WALL0 + (t if stamped is None else stamped))}


def line(x: float) -> float:
    return 10.0 + 12.0 * (x - REF_MM) / 1000.0


def test_a_position_older_than_its_bound_holds_the_axis() -> None:
    cycle = Cycle(positional(), sp2())
    clock = FakeClock(period_s=1.0)
    for _ in range(3):
        t = clock.tick()
        plan = cycle.plan(t, at(t, 525.0), wall_s=WALL0 + t)
        row = cycle.commit()
    assert plan.writes["x_comp_offset"] == pytest.approx(line(525.0))
    assert "x_comp_value" not in plan.writes
    assert row.axes["x"].offset_um == pytest.approx(16.0)
    # the controller's position stops coming (its source stamp stays at t0) while the
    # axis moves on: within the bound it is still the position, past it the axis holds
    t0 = t
    stale = None
    for _ in range(8):
        t = clock.tick()
        plan = cycle.plan(t, at(t, 900.0, stamped=t0), wall_s=WALL0 + t)
        row = cycle.commit()
        if row.axes["x"].cause == Cause.INPUTS_INVALID and stale is None:
            stale = t - t0
            held = plan.writes["x_comp_offset"]
    assert stale is not None and 5.0 < stale <= 6.0
    # held at the offset of the last position within its age (the stamp was still
    # recent when the axis reached 900 mm)
    assert held == pytest.approx(line(900.0))
    assert row.axes["x"].cause == Cause.INPUTS_INVALID
    assert plan.writes["x_comp_offset"] == pytest.approx(held)
    assert row.cause.healthy  # the offset's own output goes on
    # a fresh position: the line at it, at once
    t = clock.tick()
    plan = cycle.plan(t, at(t, 100.0), wall_s=WALL0 + t)
    row = cycle.commit()
    assert plan.writes["x_comp_offset"] == pytest.approx(line(100.0))
    assert row.axes["x"].cause == Cause.AT_LIMIT  # healthy: the slope model asks 15 µm/m


def test_a_position_not_a_number_holds_the_axis_at_its_last_offset() -> None:
    cycle = Cycle(positional(), sp2())
    clock = FakeClock(period_s=1.0)
    for _ in range(3):
        t = clock.tick()
        cycle.plan(t, at(t, 525.0), wall_s=WALL0 + t)
        cycle.commit()
    t = clock.tick()
    plan = cycle.plan(t, at(t, float("nan")), wall_s=WALL0 + t)
    row = cycle.commit()
    assert row.axes["x"].cause == Cause.INPUTS_INVALID
    assert plan.writes["x_comp_offset"] == pytest.approx(line(525.0))
    assert row.axes["x"].position_mm == 525.0


def test_a_restarted_controller_is_ramped_from_at_the_value_rate() -> None:
    cycle = Cycle(positional(readback=True, value_slew_um_s=1.0), sp2())
    clock = FakeClock(period_s=1.0)
    rb = 0.0  # the controller holds 0 at start
    for _ in range(20):
        t = clock.tick()
        plan = cycle.plan(t, at(t, 525.0), 0.0, wall_s=WALL0 + t,
                          axes_readback={"x_comp_offset": rb})
        row = cycle.commit()
        rb = plan.writes["x_comp_offset"]
    assert rb == pytest.approx(line(525.0)) and row.axes["x"].cause == Cause.AT_LIMIT
    # the controller restarts: its offset register reads 0 at 525 mm
    t = clock.tick()
    plan = cycle.plan(t, at(t, 525.0), 0.0, wall_s=WALL0 + t,
                      axes_readback={"x_comp_offset": 0.0})
    row = cycle.commit()
    assert any(e.name is EventName.READBACK_MISMATCH and e.fields.get("axis") == "x"
               for e in plan.events)
    assert row.axes["x"].cause == Cause.FOREIGN_OFFSET
    # from 0, one second at 1 µm/s: the value's step, the slope unchanged
    assert plan.writes["x_comp_offset"] == pytest.approx(1.0)


def test_a_hold_keeps_the_offset_as_written_while_the_axis_moves() -> None:
    """The operator's hold (and a controller not permitting a change) keeps the whole
    offset, the motion's part too: released, the line at the present position."""
    cycle = Cycle(positional(), sp2())
    clock = FakeClock(period_s=1.0)
    for _ in range(3):
        t = clock.tick()
        cycle.plan(t, at(t, 525.0), wall_s=WALL0 + t)
        cycle.commit()
    assert cycle.set_operator_hold(True, "test") is not None
    for x in (600.0, 900.0):
        t = clock.tick()
        plan = cycle.plan(t, at(t, x), wall_s=WALL0 + t)
        row = cycle.commit()
        assert plan.writes["x_comp_offset"] == pytest.approx(line(525.0))
        assert row.axes["x"].position_mm == 525.0
    cycle.set_operator_hold(False, "test")
    t = clock.tick()
    plan = cycle.plan(t, at(t, 900.0), wall_s=WALL0 + t)
    cycle.commit()
    assert plan.writes["x_comp_offset"] == pytest.approx(line(900.0))


def test_a_position_faster_than_the_rapid_traverse_holds_the_axis() -> None:
    """With max_rate_per_s at the rapid traverse (500 mm/s), a traverse of 375 mm in
    a second is motion; 900 mm in a second is a glitch, refused, the axis held."""
    cycle = Cycle(positional(rapid_mm_s=500.0), sp2())
    clock = FakeClock(period_s=1.0)
    for x in (525.0, 525.0, 900.0):
        t = clock.tick()
        plan = cycle.plan(t, at(t, x), wall_s=WALL0 + t)
        row = cycle.commit()
    assert plan.writes["x_comp_offset"] == pytest.approx(line(900.0))
    t = clock.tick()
    plan = cycle.plan(t, at(t, 0.0), wall_s=WALL0 + t)
    row = cycle.commit()
    assert plan.validity["x_pos"] == "rate"
    assert row.axes["x"].cause == Cause.INPUTS_INVALID
    assert plan.writes["x_comp_offset"] == pytest.approx(line(900.0))
