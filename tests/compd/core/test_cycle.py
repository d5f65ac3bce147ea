"""The pure cycle with a fake clock: hours of machine time in milliseconds."""

from __future__ import annotations

import math

import pytest

from compd.core.cycle import Cycle, Outcome
from compd.core.output import Status
from compd.testing import FakeClock
from drivers.base import Quality, Sample
from tests.compd.core.cycle_helpers import (
    HOLD_S,
    LIMIT_UM,
    PERIOD_S,
    SLEW_UM_S,
    params,
    run_warm,
    samples,
    sp2,
)


def _events(result: object) -> list[str]:
    return [e.name for e in result.events]  # type: ignore[attr-defined]


def test_first_start_takes_current_temperatures_as_reference() -> None:
    cycle, clock = Cycle(params(), sp2()), FakeClock()
    t = clock.tick()
    r = cycle.plan(t, samples(t, 30.0, 21.0))
    assert "model_initialised" in _events(r)
    assert r.inputs_valid and r.model_um == pytest.approx(0.0, abs=1e-9)
    assert cycle.models.model.references == {"bearing": 30.0, "ambient": 21.0}
    assert r.writes["offset"] == 0.0 and r.writes["heartbeat"] == 1.0
    assert r.status & Status.OK


def test_heating_is_followed_within_the_slew_limit() -> None:
    cycle, clock = Cycle(params(), sp2()), FakeClock()
    run_warm(cycle, clock, 5, bearing=20.0)
    previous = 0.0
    bearing = 20.0
    for _ in range(3 * 3600):  # 3 h of machine time, bearing +1 K/h
        t = clock.tick()
        bearing += 1.0 / 3600.0
        cycle.plan(t, samples(t, round(bearing, 1)))
        r = cycle.commit()
        assert abs(r.stage_um - previous) <= SLEW_UM_S * PERIOD_S + 1e-9
        previous = r.stage_um
    assert r.model_um is not None and r.model_um > 10.0
    assert r.stage_um == pytest.approx(r.model_um, abs=1.0)


def test_warm_restart_with_an_old_checkpoint_starts_at_the_steady_state() -> None:
    # the references were taken cold (20 °C); today the bearing is at 24 °C
    state = {"model": {"references": {"bearing": 20.0, "ambient": 20.0}, "terms": {}},
             "offset_um": 40.0, "sequence": 7}
    cycle = Cycle.from_state(params(), sp2(), None, state, fresh=False)
    t = 1.0
    r = cycle.plan(t, samples(t, 24.0, 20.0))
    steady = sp2()
    steady.set_references({"bearing": 20.0, "ambient": 20.0})
    expected = steady.steady_state({"bearing": 24.0, "ambient": 20.0})
    assert expected > 50.0  # a warm machine: far from zero
    assert r.model_um == pytest.approx(expected, rel=1e-6)
    # the output starts from the last written offset, slew-limited
    assert r.stage_um == pytest.approx(40.0 + SLEW_UM_S * PERIOD_S)
    assert r.sequence == 8


def test_fresh_checkpoint_resumes_the_filters_exactly() -> None:
    a, clock = Cycle(params(), sp2()), FakeClock()
    run_warm(a, clock, 50, bearing=20.0)
    run_warm(a, clock, 100, bearing=22.0)
    b = Cycle.from_state(params(), sp2(), None, a.export_state(), fresh=True)
    b._last_now = clock.now_s
    for _ in range(20):
        t = clock.tick()
        a.plan(t, samples(t, 22.5))
        b.plan(t, samples(t, 22.5))
        ra = a.commit()
        rb = b.commit()
        assert rb.model_um == ra.model_um
        assert rb.stage_um == ra.stage_um


@pytest.mark.parametrize(("bearing", "reason"), [
    (math.nan, "not_finite"), (850.0, "out_of_range"), (-200.0, "out_of_range"),
    (math.inf, "not_finite")])
def test_bad_value_holds_then_ramps_at_hold_s_and_recovers_without_jump(
        bearing: float, reason: str) -> None:
    cycle, clock = Cycle(params(), sp2()), FakeClock()
    run_warm(cycle, clock, 10, bearing=20.0)
    run_warm(cycle, clock, 80, bearing=22.0)  # offset slews up to ~32 µm
    held = cycle.output.current_um
    model_state = cycle.models.model.export_state()
    fault_start = clock.tick()
    plan = cycle.plan(fault_start, samples(fault_start, bearing))
    assert plan.validity["bearing"] == reason
    assert plan.state == "hold" and plan.stage_um == held and not plan.inputs_valid
    assert plan.status & Status.HOLDING and "fault_hold" in _events(plan)
    heartbeat = plan.heartbeat
    ramp_started: float | None = None
    while clock.now_s < fault_start + HOLD_S + 40 * PERIOD_S:
        t = clock.tick()
        cycle.plan(t, samples(t, bearing))
        r = cycle.commit()
        assert r.heartbeat == heartbeat  # the heartbeat stops on invalid cycles
        if r.state == "ramp" and ramp_started is None:
            ramp_started = t
            assert r.status & Status.ALARM and r.status & Status.RAMPING
    assert cycle.models.model.export_state() == model_state  # filters never saw the bad value
    assert ramp_started is not None
    assert abs(ramp_started - (fault_start + HOLD_S)) <= PERIOD_S
    assert held > 20.0
    assert r.stage_um == pytest.approx(
        max(0.0, held - SLEW_UM_S * (clock.now_s - ramp_started + PERIOD_S)), abs=1e-9)
    # recovery: valid again, the offset moves toward the model without a jump
    before = r.stage_um
    t = clock.tick()
    plan = cycle.plan(t, samples(t, 22.0))
    assert plan.inputs_valid and plan.state == "ok" and "fault_recovered" in _events(plan)
    assert abs(plan.stage_um - before) <= SLEW_UM_S * PERIOD_S + 1e-9
    assert not plan.status & Status.ALARM


def test_read_failure_holds_then_ramps_to_zero() -> None:
    cycle, clock = Cycle(params(), sp2()), FakeClock()
    run_warm(cycle, clock, 10, bearing=20.0)
    run_warm(cycle, clock, 40, bearing=21.0)
    held = cycle.output.current_um
    start = clock.tick()
    plan = cycle.plan(start, None)
    assert plan.state == "hold" and plan.stage_um == held
    assert set(plan.validity.values()) == {"read_failed"}
    for _ in range(int(HOLD_S + held / SLEW_UM_S) + 5):
        t = clock.tick()
        cycle.plan(t, None)
        r = cycle.commit()
    assert r.state == "ramp" and r.stage_um == 0.0 and r.writes["offset"] == 0.0


def test_invalid_from_the_start_holds_then_ramps_with_the_alarm() -> None:
    """A sensor broken across a restart: the restored offset is held (status
    HOLDING, not 0), then ramped to zero with the alarm after hold_s, never held
    stale in init forever with no alarm."""
    warm, clock = Cycle(params(), sp2()), FakeClock()
    run_warm(warm, clock, 10, bearing=20.0)
    run_warm(warm, clock, 60, bearing=22.0)
    state = warm.export_state()
    held = state["offset_um"]
    assert held > 5.0
    cycle = Cycle.from_state(params(), sp2(), None, state, fresh=True)
    cycle._last_now = clock.now_s
    t = clock.tick()
    plan = cycle.plan(t, samples(t, 900.0))  # an open Pt100
    assert plan.state == "init" and plan.stage_um == held
    assert plan.status & Status.HOLDING and not plan.status & Status.ALARM
    for _ in range(int(HOLD_S) + int(held / SLEW_UM_S) + 5):
        t = clock.tick()
        cycle.plan(t, samples(t, 900.0))
        r = cycle.commit()
    assert r.state == "ramp" and r.stage_um == 0.0
    assert r.status & Status.ALARM and r.status & Status.RAMPING


def test_one_sample_spike_is_rejected_and_filters_not_stepped() -> None:
    ref, spiked, clock = Cycle(params(), sp2()), Cycle(params(), sp2()), FakeClock()
    for k in range(200):
        t = clock.tick()
        b = 40.0 + 0.001 * k
        ref.plan(t, samples(t, b))
        if k in (100, 150):
            plan = spiked.plan(t, samples(t, b + (50.0 if k == 100 else -50.0)))
            assert plan.validity["bearing"] == "rate"
            assert plan.state == "hold"
            ref_state = ref.models.model.export_state()
            continue
        spiked.plan(t, samples(t, b))
        ra = ref.commit()
        rb = spiked.commit()
    assert ref_state is not None
    # the spiked run skipped two samples but never saw the spike: same model output
    # as a run that skipped nothing, to the effect of two missing samples only
    assert rb.model_um == pytest.approx(ra.model_um, abs=0.05)


def test_stuck_value_is_flagged_only_while_others_move() -> None:
    cycle, clock = Cycle(params(), sp2()), FakeClock(period_s=10.0)
    # the bearing freezes at 25.0 while the ambient keeps moving
    reasons = []
    for k in range(500):
        t = clock.tick()
        r = cycle.plan(t, samples(t, 25.0, 20.0 + 0.01 * (k % 2)))
        reasons.append(r.validity["bearing"])
    assert reasons[300] is None  # 3000 s < stuck_after_s = 3600 s
    assert reasons[-1] == "stuck"


def test_quantised_slowly_heating_sensor_is_not_stuck() -> None:
    # 0.1 K quantisation, heating at 0.5 K/h: a new value every 12 min
    cycle, clock = Cycle(params(), sp2()), FakeClock()
    for k in range(6 * 3600):
        t = clock.tick()
        bearing = round(20.0 + 0.5 * k / 3600.0, 1)
        cycle.plan(t, samples(t, bearing, 20.0 + 0.01 * (k % 2)))
        r = cycle.commit()
        assert r.validity["bearing"] is None, k


def test_frozen_source_timestamp_is_stale() -> None:
    cycle, clock = Cycle(params(), sp2()), FakeClock()
    run_warm(cycle, clock, 10)
    frozen_ts = clock.now_s
    reasons = []
    for _ in range(40):
        t = clock.tick()
        r = cycle.plan(t, samples(t, 25.0, ts_s=frozen_ts))
        reasons.append(r.validity["bearing"])
    assert reasons[0] is None and reasons[-1] == "stale"
    # an old timestamp against the wall clock is stale at once
    t = clock.tick()
    r = cycle.plan(t, samples(t, 25.0, ts_s=1000.0), wall_s=1000.0 + 31.0)
    assert r.validity["bearing"] == "stale"


def test_bad_quality_and_missing_channel_hold() -> None:
    cycle, clock = Cycle(params(), sp2()), FakeClock()
    run_warm(cycle, clock, 10)
    t = clock.tick()
    r = cycle.plan(t, samples(t, 25.0, quality=Quality.BAD))
    assert r.state == "hold"
    t = clock.tick()
    r = cycle.plan(t, {"ambient": Sample(20.0, t), "spindle_rpm": Sample(0.0, t)})
    assert r.validity["bearing"] == "missing"


def test_invalid_monitoring_channel_does_not_stop_compensation() -> None:
    cycle, clock = Cycle(params(), sp2()), FakeClock()
    run_warm(cycle, clock, 10)
    t = clock.tick()
    r = cycle.plan(t, samples(t, 25.0, speed=-5.0))  # speed is not a model input
    assert r.inputs_valid and r.state == "ok"
    assert r.validity["spindle_rpm"] == "out_of_range"


def test_permanent_write_rejection_stops_offset_writes_and_alarms() -> None:
    cycle, clock = Cycle(params(), sp2()), FakeClock()
    run_warm(cycle, clock, 5, bearing=20.0)
    t = clock.tick()
    r = cycle.plan(t, samples(t, 21.0))
    ev = cycle.commit(Outcome.failed("offset", permanent=True, reason="not writable")).write_events
    assert [e.name for e in ev] == ["offset_write_stopped"]
    t = clock.tick()
    r = cycle.plan(t, samples(t, 21.0))
    assert "offset" not in r.writes and "heartbeat" in r.writes
    assert r.status & Status.WRITE_STOPPED and r.status & Status.ALARM
    assert not r.status & Status.OK


def test_transient_write_failure_is_retried_from_the_confirmed_value() -> None:
    cycle, clock = Cycle(params(), sp2()), FakeClock()
    run_warm(cycle, clock, 5, bearing=20.0)
    confirmed = cycle.output.current_um
    for _ in range(3):
        t = clock.tick()
        plan = cycle.plan(t, samples(t, 20.4))
        cycle.commit(Outcome.failed("offset", permanent=False, reason="busy"))
        assert plan.writes["offset"] == pytest.approx(confirmed + SLEW_UM_S * PERIOD_S)
    t = clock.tick()
    cycle.plan(t, samples(t, 20.4))
    r = cycle.commit()
    assert r.writes["offset"] == pytest.approx(confirmed + SLEW_UM_S * PERIOD_S)


def test_readback_mismatch_ramps_from_the_controller_value() -> None:
    cycle, clock = Cycle(params(readback=True), sp2()), FakeClock()
    t = clock.tick()
    r = cycle.plan(t, samples(t, 20.0), 0.0)
    assert "readback_adopted" in _events(r)
    cycle.commit()
    controller = 0.0
    for _ in range(60):
        t = clock.tick()
        cycle.plan(t, samples(t, 22.0), controller)
        row = cycle.commit()
        controller = row.writes["offset"]
    assert controller > 30.0
    # the controller restarts and forgets the offset
    t = clock.tick()
    r = cycle.plan(t, samples(t, 22.0), 0.0)
    assert "readback_mismatch" in _events(r) and r.status & Status.READBACK_MISMATCH
    assert r.writes["offset"] == pytest.approx(SLEW_UM_S * PERIOD_S)
    # read failed: the controller's state is unknown, no offset write
    t = clock.tick()
    r = cycle.plan(t, None, None)
    assert "offset" not in r.writes and "offset_write_skipped" in _events(r)


def test_limit_clamps_the_output() -> None:
    cycle, clock = Cycle(params(slew_um_s=1000.0), sp2()), FakeClock()
    run_warm(cycle, clock, 5, bearing=20.0)
    run_warm(cycle, clock, 50, bearing=40.0)
    assert cycle.output.current_um == LIMIT_UM


def test_sign_and_scale_convert_to_controller_units() -> None:
    cycle, clock = Cycle(params(sign=-1, units_per_um=0.001, slew_um_s=1000.0),
                         sp2()), FakeClock()
    run_warm(cycle, clock, 5, bearing=20.0)
    t = clock.tick()
    r = cycle.plan(t, samples(t, 20.5))
    assert r.writes["offset"] == pytest.approx(-0.001 * r.stage_um)
    assert r.stage_um > 0


def test_shutdown_ramp_to_zero_finishes_at_zero() -> None:
    cycle, clock = Cycle(params(), sp2()), FakeClock()
    run_warm(cycle, clock, 5, bearing=20.0)
    run_warm(cycle, clock, 30, bearing=22.0)
    start = cycle.output.current_um
    cycle.begin_shutdown()
    n = 0
    while True:
        t = clock.tick()
        cycle.plan(t, samples(t, 22.0))
        r = cycle.commit()
        n += 1
        if r.shutdown_done:
            break
    assert r.stage_um == 0.0 and r.status & Status.SHUTDOWN
    assert n == math.ceil(start / SLEW_UM_S)


def test_deadband_keeps_small_changes_out() -> None:
    cycle, clock = Cycle(params(deadband_um=0.5, slew_um_s=100.0), sp2()), FakeClock()
    run_warm(cycle, clock, 5, bearing=20.0)
    t = clock.tick()
    r = cycle.plan(t, samples(t, 20.02))  # ≈0.32 µm
    assert r.stage_um == 0.0
    t = clock.tick()
    r = cycle.plan(t, samples(t, 20.1))
    assert r.stage_um > 0.5


def test_shadow_model_is_evaluated_but_never_written() -> None:
    from compd.infiles import load_model
    shadow = load_model("sp2")
    shadow.terms[0].gain = 2.0
    cycle, clock = Cycle(params(slew_um_s=1000.0), sp2(), shadow), FakeClock()
    run_warm(cycle, clock, 5, bearing=20.0)
    t = clock.tick()
    r = cycle.plan(t, samples(t, 20.5))
    assert r.shadow_um is not None and r.model_um is not None
    assert r.shadow_um == pytest.approx(2 * r.model_um, rel=0.01)
    assert r.writes["offset"] == r.stage_um == pytest.approx(r.model_um)
    assert r.contributions["shadow_total"] == r.shadow_um


def test_heartbeat_wraps() -> None:
    cycle, clock = Cycle(params(), sp2(), heartbeat=32767), FakeClock()
    t = clock.tick()
    r = cycle.plan(t, samples(t, 20.0))
    assert r.heartbeat == 0


def test_a_cycle_steps_a_model_of_its_own_and_leaves_the_description_as_it_was() -> None:
    """The model given (a config's) is a description: two cycles built from it step
    states of their own, and the description keeps no reference state nor filter state,
    so a reload, a restart or a replay may build another cycle from it."""
    model = sp2()
    described = model.export_state()
    first, second = Cycle(params(), model), Cycle(params(), model)
    clock = FakeClock()
    run_warm(first, clock, 10, bearing=25.0)
    run_warm(first, clock, 20, bearing=25.3)  # its filters move off the steady state
    assert first.models.model is not model and first.models.model is not second.models.model
    assert model.export_state() == described and model.references == {}
    assert first.models.model.references == {"bearing": 25.0, "ambient": 20.0}
    later = FakeClock()
    run_warm(second, later, 30, bearing=30.0)  # its own first sample: its own reference
    assert second.models.model.references == {"bearing": 30.0, "ambient": 20.0}
    assert first.models.model.references == {"bearing": 25.0, "ambient": 20.0}
    assert first.export_state()["model"]["terms"] != model.export_state()["terms"]
