"""A value in the offset register that compd did not write:
an alarm, and never a step at the tool: within ±limit the output ramps from
it; beyond, no offset is written until the controller's value is back."""

from __future__ import annotations

import math

import pytest

from compd.core.cycle import Cycle, Plan, Row
from compd.core.output import OutputStage, Readback, Status
from compd.testing import FakeClock
from tests.compd.core.cycle_helpers import LIMIT_UM, PERIOD_S, SLEW_UM_S, params, samples, sp2


def _names(r: Plan | Row) -> list[str]:
    return [e.name for e in r.events]


def _warm(cycle: Cycle, clock: FakeClock, n: int, bearing: float) -> float:
    """`n` cycles with read-back, each write confirmed; what the controller holds."""
    controller = cycle.output.current_um
    for _ in range(n):
        t = clock.tick()
        cycle.plan(t, samples(t, bearing), controller)
        r = cycle.commit()
        controller = r.writes.get("offset", controller)
    return controller


def _heated() -> tuple[Cycle, FakeClock, float]:
    cycle, clock = Cycle(params(readback=True), sp2()), FakeClock()
    _warm(cycle, clock, 1, 20.0)
    controller = _warm(cycle, clock, 60, 22.0)
    assert controller > 30.0 and not cycle.output.slewing
    return cycle, clock, controller


def test_foreign_value_within_limit_alarms_and_ramps_from_it() -> None:
    cycle, clock, before = _heated()
    foreign = -50.0
    t = clock.tick()
    plan = cycle.plan(t, samples(t, 22.0), foreign)
    assert "readback_mismatch" in _names(plan)
    assert plan.status & Status.ALARM and plan.status & Status.READBACK_MISMATCH
    assert plan.writes["offset"] == pytest.approx(foreign + SLEW_UM_S * PERIOD_S)
    r = cycle.commit()
    controller = r.writes["offset"]
    alarms = 1
    while cycle.output.slewing or r.status & Status.ALARM:
        t = clock.tick()
        cycle.plan(t, samples(t, 22.0), controller)
        r = cycle.commit()
        assert abs(r.writes["offset"] - controller) <= SLEW_UM_S * PERIOD_S + 1e-9
        controller = r.writes["offset"]
        alarms += bool(r.status & Status.ALARM)
    # the alarm lasted while the output ramped back, then cleared by itself
    assert alarms >= (before - foreign) / SLEW_UM_S - 2
    assert controller == pytest.approx(before, abs=0.05)
    assert r.status & Status.OK and not r.status & Status.ALARM


def test_foreign_value_beyond_limit_holds_writes_until_cleared() -> None:
    cycle, clock, before = _heated()
    held_events = 0
    for _ in range(5):
        t = clock.tick()
        cycle.plan(t, samples(t, 22.0), 1000.0)
        r = cycle.commit()
        held_events += _names(r).count("readback_out_of_range")
        # no offset write at all (198.998 would be an 801 µm step); heartbeat and
        # status go on and say so
        assert "offset" not in r.writes
        assert r.writes["heartbeat"] == r.heartbeat and r.inputs_valid
        status = int(r.writes["status"])
        assert status & Status.OFFSET_HELD and status & Status.ALARM
        assert not status & Status.OK
        assert r.state == "held"
    assert held_events == 1
    # a read failure in between: still held, still no offset
    t = clock.tick()
    plan = cycle.plan(t, samples(t, 22.0), None)
    assert "offset" not in plan.writes and plan.status & Status.OFFSET_HELD
    # an operator clears the register: ramp from 0, alarm until back on target
    controller = 0.0
    t = clock.tick()
    plan = cycle.plan(t, samples(t, 22.0), controller)
    assert "readback_in_range" in _names(plan) and plan.status & Status.ALARM
    assert plan.writes["offset"] == pytest.approx(SLEW_UM_S * PERIOD_S)
    r = cycle.commit()
    controller = r.writes["offset"]
    for _ in range(80):
        t = clock.tick()
        cycle.plan(t, samples(t, 22.0), controller)
        r = cycle.commit()
        assert abs(r.writes["offset"] - controller) <= SLEW_UM_S * PERIOD_S + 1e-9
        controller = r.writes["offset"]
    assert controller == pytest.approx(before, abs=0.05)
    assert r.state == "ok" and r.status & Status.OK and not r.status & Status.ALARM


def test_not_a_number_in_the_register_holds() -> None:
    cycle, clock, _ = _heated()
    t = clock.tick()
    r = cycle.plan(t, samples(t, 22.0), math.nan)
    assert "offset" not in r.writes and r.status & Status.OFFSET_HELD
    assert r.state == "held"


def test_start_up_with_a_value_beyond_the_limit_holds() -> None:
    cycle, clock = Cycle(params(readback=True), sp2()), FakeClock()
    t = clock.tick()
    r = cycle.plan(t, samples(t, 20.0), -1000.0)
    assert "offset" not in r.writes and "readback_out_of_range" in _names(r)
    assert r.status & Status.OFFSET_HELD and r.status & Status.ALARM
    t = clock.tick()
    r = cycle.plan(t, samples(t, 20.0), -LIMIT_UM)  # cleared to a value within
    assert r.writes["offset"] == pytest.approx(-LIMIT_UM + SLEW_UM_S * PERIOD_S)


def test_start_up_from_a_checkpoint_with_a_foreign_value_alarms() -> None:
    cycle, clock, _ = _heated()
    restarted = Cycle.from_state(cycle.params, sp2(), None, cycle.export_state(), fresh=True)
    t = clock.tick()
    r = restarted.plan(t, samples(t, 22.0), 5.0)
    assert "readback_mismatch" in _names(r) and r.status & Status.ALARM
    assert r.writes["offset"] == pytest.approx(5.0 + SLEW_UM_S * PERIOD_S)


def test_shutdown_ramp_ends_when_the_offset_is_held() -> None:
    cycle, clock, _ = _heated()
    cycle.begin_shutdown()
    t = clock.tick()
    r = cycle.plan(t, samples(t, 22.0), 1e6)
    assert r.shutdown_done and "offset" not in r.writes


@pytest.mark.parametrize(("value", "seen"), [
    (0.0, Readback.FOREIGN), (10.004, Readback.MATCH), (-LIMIT_UM, Readback.FOREIGN),
    (LIMIT_UM * (1 + 1e-7), Readback.FOREIGN), (LIMIT_UM * 1.001, Readback.OUT_OF_RANGE),
    (math.inf, Readback.OUT_OF_RANGE), (math.nan, Readback.OUT_OF_RANGE)])
def test_output_stage_observe(value: float, seen: Readback) -> None:
    stage = OutputStage(limit_um=LIMIT_UM, slew_um_s=SLEW_UM_S, initial_um=10.0)
    stage.confirm()
    assert stage.observe(value, 0.01) is seen
    assert stage.held == (seen is Readback.OUT_OF_RANGE)
    out = stage.step(50.0, 1.0)
    if stage.held:
        assert out == 10.0  # held: not moved
    else:
        assert abs(out) <= LIMIT_UM
        assert abs(out - min(value, LIMIT_UM)) <= SLEW_UM_S + 1e-9
