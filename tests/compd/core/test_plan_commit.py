"""The cycle as plan and commit: what a cycle returns is
never changed afterwards, one commit closes one plan, and the status word and
the recorded state are pure functions of one frozen health view."""

from __future__ import annotations

import itertools

import pytest

from compd.core.cycle import WRITTEN, Cycle, Outcome
from compd.core.faults import FaultState
from compd.core.health import Cause
from compd.core.health_view import HealthView, output_cause, recorded_state, status_word
from compd.core.output import Status
from compd.testing import FakeClock
from tests.compd.core.cycle_helpers import params, run_warm, samples, sp2


def _warm() -> tuple[Cycle, FakeClock]:
    cycle, clock = Cycle(params(), sp2()), FakeClock()
    run_warm(cycle, clock, 5, bearing=20.0)
    return cycle, clock


def test_a_failed_write_is_in_the_row_and_leaves_the_plan_as_it_was() -> None:
    cycle, clock = _warm()
    t = clock.tick()
    plan = cycle.plan(t, samples(t, 20.5))
    before = plan._replace()
    row = cycle.commit(Outcome.failed("offset", reason="timeout"))
    assert plan == before and plan.sent_um == plan.stage_um
    assert row.sent_um == plan.stage_um and not row.write_ok
    assert row.record.offset_um is None and row.record.attempted_um == plan.stage_um
    assert [e.name for e in row.write_events] == ["write_failed"]
    assert row.events == plan.events
    with pytest.raises(AttributeError):
        row.stage_um = 0.0  # type: ignore[misc]
    with pytest.raises(TypeError):  # read-only all the way down
        row.writes["offset"] = 0.0  # type: ignore[index]


def test_a_confirmed_write_completes_the_row_and_the_snapshot_says_what_is_in_force() -> None:
    cycle, clock = _warm()
    t = clock.tick()
    plan = cycle.plan(t, samples(t, 20.5))
    row = cycle.commit(WRITTEN)
    assert row.record.complete and row.in_force
    assert row.confirmed_um == plan.stage_um
    assert row.snapshot.operator_hold is False and row.snapshot.adaptation is None


def test_one_commit_per_plan() -> None:
    cycle, clock = _warm()
    with pytest.raises(RuntimeError):
        cycle.commit()  # run_warm committed its last plan
    t = clock.tick()
    cycle.plan(t, samples(t, 20.0))
    cycle.commit()
    with pytest.raises(RuntimeError):
        cycle.commit()


def test_an_operator_hold_is_in_the_snapshot_and_turns_ok_into_holding() -> None:
    cycle, clock = _warm()
    assert cycle.set_operator_hold(True, "test") is not None
    t = clock.tick()
    cycle.plan(t, samples(t, 20.0))
    row = cycle.commit()
    assert row.snapshot.operator_hold and row.state == FaultState.OK
    assert row.status & Status.OPERATOR_HOLD and row.status & Status.HOLDING
    assert not row.status & Status.OK


_FLAGS = ("write_stopped", "write_fault", "held", "foreign", "operator_hold")


@pytest.mark.parametrize("policy", [FaultState.INIT, FaultState.OK, FaultState.HOLD,
                                    FaultState.RAMP, FaultState.SHUTDOWN])
def test_status_word_and_recorded_state_agree_for_every_health(policy: FaultState) -> None:
    invalid = None if policy in (FaultState.OK, FaultState.SHUTDOWN) else Cause.INPUTS_INVALID
    for bits in itertools.product([False, True], repeat=len(_FLAGS)):
        stopped, fault, held, foreign, hold = bits
        view = HealthView(policy=policy, invalid=invalid, write_stopped=stopped,
                          write_fault=fault, held=held, foreign=foreign, operator_hold=hold)
        word, state, cause = status_word(view), recorded_state(view), output_cause(view)
        # OK on the wire exactly when the recorded state is ok and no operator holds it
        assert bool(word & Status.OK) == (state == FaultState.OK and not view.operator_hold)
        # an alarm state (stopped, held, write fault) always raises the alarm bit
        if state.gauge >= 3:
            assert word & Status.ALARM
        # healthy (the offset compd wants in force, or held by an operator) only when the
        # state is ok and no alarm is raised; OK on the wire without an alarm is in force
        if cause.healthy:
            assert state == FaultState.OK and not word & Status.ALARM
        if word & Status.OK and not word & Status.ALARM:
            assert cause is Cause.IN_FORCE
        assert status_word(view) == word  # pure: the same view, the same word


def test_a_refused_combined_write_names_each_output_as_the_driver_did() -> None:
    """`Outcome.failed` takes a driver error's channel tuple: each output is its
    own, a name is never split, and one name alone may be a string."""
    cycle, clock = _warm()
    t = clock.tick()
    cycle.plan(t, samples(t, 20.5))
    row = cycle.commit(Outcome.failed(("heartbeat", "status"), permanent=True, reason="ro"))
    assert [(e.name, e.fields["output"]) for e in row.write_events] == [
        ("output_write_stopped", "heartbeat"), ("output_write_stopped", "status")]
    assert Outcome.failed("offset").outputs == ("offset",)
    assert Outcome.failed(None).outputs == () and Outcome.failed([]).outputs == ()
    t = clock.tick()
    plan = cycle.plan(t, samples(t, 20.5))
    assert set(plan.writes) == {"offset"}  # the stopped outputs are written no more
    row = cycle.commit(Outcome.failed(("offset", "heartbeat"), reason="busy"))
    assert [(e.name, e.fields["output"]) for e in row.write_events] == [
        ("write_failed", "offset,heartbeat")]  # the log line's field, as before
