"""Each cycle names why the offset compd wants is not in force, or that it is
(`compd.core.health.Cause`), on the fake clock: the cause follows the real
reason, and the fault policy's hold and ramp events carry it as ``reason``
(a model worse than none was once logged as ``invalid_for_s`` and shown as
"inputs invalid")."""

from __future__ import annotations

import math

import pytest

from compd.core.adaptation import AdaptationSettings
from compd.core.cycle import Cycle, Outcome
from compd.core.health import Cause
from compd.core.plan import Row
from compd.faces.status import operator_state
from compd.testing import FakeClock
from models.adaptation import AdaptationParams
from tests.compd.core.cycle_helpers import HOLD_S, params, run_warm, samples, sp2


def _step(cycle: Cycle, clock: FakeClock, bearing: float | None,
          outcome: Outcome | None = None) -> Row:
    t = clock.tick()
    cycle.plan(t, None if bearing is None else samples(t, bearing))
    return cycle.commit() if outcome is None else cycle.commit(outcome)


def _reasons(rows: list[Row], name: str) -> list[object]:
    return [e.fields.get("reason") for r in rows for e in r.events if e.name == name]


def test_invalid_inputs_hold_and_ramp_with_their_reason_and_recover_in_force() -> None:
    cycle, clock = Cycle(params(), sp2()), FakeClock()
    run_warm(cycle, clock, 30, bearing=21.0)
    assert _step(cycle, clock, 21.0).cause is Cause.IN_FORCE
    rows = [_step(cycle, clock, math.nan) for _ in range(int(HOLD_S) + 2)]
    assert {r.cause for r in rows} == {Cause.INPUTS_INVALID}
    assert not any(r.healthy or r.in_force for r in rows)
    assert _reasons(rows, "fault_hold") == ["inputs_invalid"]
    assert _reasons(rows, "fault_ramp_to_zero") == ["inputs_invalid"]
    ramp = next(e for r in rows for e in r.events if e.name == "fault_ramp_to_zero")
    assert ramp.fields["fault_for_s"] >= HOLD_S and "invalid_for_s" not in ramp.fields
    back = _step(cycle, clock, 21.0)
    assert [e.fields["was"] for e in back.events if e.name == "fault_recovered"] == [
        "inputs_invalid"]
    assert back.cause is Cause.IN_FORCE and back.healthy


def test_a_failed_read_is_the_controller_not_answering() -> None:
    cycle, clock = Cycle(params(), sp2()), FakeClock()
    run_warm(cycle, clock, 5, bearing=21.0)
    row = _step(cycle, clock, None)
    assert row.cause is Cause.CONTROLLER_NOT_ANSWERING and not row.healthy


def test_a_failed_offset_write_is_named_and_a_fault_after_several() -> None:
    cycle, clock = Cycle(params(), sp2()), FakeClock()
    run_warm(cycle, clock, 5, bearing=21.0)
    failed = Outcome.failed("offset", reason="timeout")
    causes = [_step(cycle, clock, 21.0, failed).cause for _ in range(6)]
    assert causes[0] is Cause.WRITE_FAILED and causes[-1] is Cause.WRITE_FAULT
    refused = Outcome.failed("offset", permanent=True, reason="read-only")
    assert _step(cycle, clock, 21.0, refused).cause is Cause.WRITE_STOPPED


def test_an_operator_hold_is_healthy_and_a_model_beyond_the_limit_is_not() -> None:
    cycle, clock = Cycle(params(limit_um=10.0), sp2()), FakeClock()
    run_warm(cycle, clock, 5, bearing=20.0)
    assert _step(cycle, clock, 20.0).cause is Cause.IN_FORCE
    assert cycle.set_operator_hold(True, "test") is not None
    held = _step(cycle, clock, 20.0)
    assert held.cause is Cause.OPERATOR_HOLD and held.healthy and held.in_force
    cycle.set_operator_hold(False, "test")
    hot = [_step(cycle, clock, 20.0 + 0.4 * k) for k in range(1, 6)]  # ~16 µm/K: > 10 µm
    assert hot[-1].model_um is not None and hot[-1].model_um > 10.0
    assert hot[-1].cause is Cause.AT_LIMIT and not hot[-1].healthy and not hot[-1].in_force


@pytest.mark.parametrize("action", ["fault", "report"])
def test_the_guard_acts_in_shadow_mode_unless_told_to_report_only(action: str) -> None:
    """The guard judges the compensation in force, which shadow mode does not
    change: its verdict holds, then ramps, in either mode; with guard_action =
    "report" it is reported (the view the page and metric read) and the offset
    stays in force."""
    settings = AdaptationSettings("shadow", "residual", AdaptationParams(),
                                  guard_window=3, guard_action=action)  # type: ignore[arg-type]
    cycle, clock = Cycle(params(adaptation=settings), sp2()), FakeClock()
    run_warm(cycle, clock, 5, bearing=21.0)
    assert cycle.probes is not None
    cycle.probes.model_worse = True  # the latch, as three accepted probes set it
    rows = [_step(cycle, clock, 21.0) for _ in range(3)]
    view = rows[-1].snapshot.adaptation
    assert view is not None and view.model_worse
    if action == "fault":
        assert {r.cause for r in rows} == {Cause.MODEL_WORSE_THAN_NONE}
        assert not rows[-1].healthy
    else:
        assert {r.cause for r in rows} == {Cause.IN_FORCE} and rows[-1].healthy
        word, why = operator_state(rows[-1].state, rows[-1].cause, {}, adaptation=view)
        assert word == "on" and "not acted on" in why
