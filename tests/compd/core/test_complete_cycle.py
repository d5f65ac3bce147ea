"""One definition of a complete cycle: the offset compd
wants is the offset in force. Valid inputs are not enough: a held output (a
foreign offset beyond the limit), a write fault, stopped writes or an
unconfirmed write make a cycle that ran, never one that completed."""

from __future__ import annotations

import itertools

import pytest

from compd.core.cycle import WRITE_FAULT_AFTER, Cycle, Outcome, offset_in_force
from compd.core.health import Cause
from compd.core.output import Status
from compd.testing import FakeClock
from tests.compd.core.cycle_helpers import params, samples, sp2


@pytest.mark.parametrize(("cause", "confirmed"),
                         list(itertools.product(list(Cause), [True, False])))
def test_only_a_confirmed_cycle_in_force_or_held_by_an_operator_is_complete(
        cause: Cause, confirmed: bool) -> None:
    # held on purpose (an operator, the controller's permit), recording only, or the
    # fallback model for a lost sensor in force (degraded: compensating, less well)
    expected = confirmed and cause in (Cause.IN_FORCE, Cause.OPERATOR_HOLD,
                                       Cause.WAITING_FOR_PERMISSION, Cause.RECORDER_ONLY,
                                       Cause.DEGRADED)
    assert offset_in_force(cause=cause, confirmed=confirmed) is expected


def _warm(readback: bool = True) -> tuple[Cycle, FakeClock, float]:
    cycle, clock = Cycle(params(readback=readback), sp2()), FakeClock()
    controller = cycle.output.current_um
    for bearing in [20.0] * 30:
        t = clock.tick()
        cycle.plan(t, samples(t, bearing), controller if readback else None)
        r = cycle.commit()
        assert r.in_force and r.record.complete
        controller = r.writes["offset"]
    return cycle, clock, controller


def test_a_held_output_has_valid_cycles_that_are_never_complete() -> None:
    cycle, clock, _ = _warm()
    for _ in range(5):
        t = clock.tick()
        cycle.plan(t, samples(t, 20.0), 1000.0)  # a foreign offset beyond the limit
        r = cycle.commit()  # heartbeat and status did arrive
        assert r.state == "held" and r.inputs_valid  # valid: the heartbeat advances
        assert not r.in_force and not r.record.complete
    t = clock.tick()
    cycle.plan(t, samples(t, 20.0), 0.0)  # cleared: ramping from 0 again
    r = cycle.commit()  # the cycle that saw the foreign value still raises its alarm
    assert r.status & Status.ALARM and r.cause is Cause.FOREIGN_OFFSET and not r.in_force
    t = clock.tick()
    cycle.plan(t, samples(t, 20.0), r.writes["offset"])  # at its target (the model's 0)
    r = cycle.commit()
    assert r.in_force and not r.status & Status.ALARM


def test_a_cycle_is_complete_only_once_the_controller_confirmed_it() -> None:
    cycle, clock, controller = _warm()
    t = clock.tick()
    plan = cycle.plan(t, samples(t, 20.0), controller)
    assert plan.sent_um is not None  # sent, not confirmed yet
    r = cycle.commit(Outcome.failed("offset", permanent=False, reason="timeout"))
    assert not r.in_force and not r.record.complete
    t = clock.tick()
    cycle.plan(t, samples(t, 20.0), controller)
    r = cycle.commit()
    assert r.in_force


def test_a_write_fault_and_stopped_writes_are_not_complete() -> None:
    cycle, clock, _ = _warm(readback=False)
    for _ in range(WRITE_FAULT_AFTER + 1):
        t = clock.tick()
        cycle.plan(t, samples(t, 20.0))
        cycle.commit(Outcome.failed("offset", permanent=False, reason="timeout"))
    t = clock.tick()
    plan = cycle.plan(t, samples(t, 20.0))
    assert plan.state == "write_fault"
    r = cycle.commit()  # the write that ends the fault: its row still says write_fault
    assert not r.in_force
    t = clock.tick()
    cycle.plan(t, samples(t, 20.0))
    r = cycle.commit()
    assert r.state == "ok" and r.in_force
    t = clock.tick()  # the next offset write is refused for good
    cycle.plan(t, samples(t, 20.0))
    cycle.commit(Outcome.failed("offset", permanent=True, reason="refused"))
    t = clock.tick()
    cycle.plan(t, samples(t, 20.0))
    r = cycle.commit()
    assert r.state == "stopped" and "offset" not in r.writes and not r.in_force


def test_invalid_inputs_are_not_complete() -> None:
    cycle, clock, _ = _warm()
    t = clock.tick()
    cycle.plan(t, None, None)  # the read failed
    r = cycle.commit()
    assert r.state == "hold" and not r.in_force
