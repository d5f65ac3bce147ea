"""The probe-assisted estimator: convergence, tracking, gate, bounds, state, covariance."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from models.adaptation import PRECISE_PROBE, STATE_VERSION, AdaptationParams, Adapter

HOUR = 3600.0


def _probe_run(adapter: Adapter, truth: list[float], every_s: float, noise_um: float,
               seed: int, terms: list[float] | None = None) -> list[float]:
    """Probe `truth` (the model's error, model output 0) every `every_s`; the filter's bias
    estimate after each (what is applied is tested below, test_*applied*)."""
    rng = np.random.default_rng(seed)
    terms = terms or [0.0]
    out = []
    for err in truth:
        adapter.advance(every_s)
        adapter.update(err + float(rng.normal(0, noise_um)), 0.0, terms)
        out.append(adapter.estimated_bias_um)
    return out


def test_worked_number_of_the_docstring() -> None:
    a = Adapter(AdaptationParams(probe_noise_um=0.5, initial_bias_sigma_um=2.0), 2)
    o = a.update(13.0, 10.0, [6.0, 4.0])
    assert o.accepted and o.reason is None
    assert o.innovation_um == pytest.approx(3.0)
    assert o.innovation_sigma_um == pytest.approx(math.sqrt(4.25))
    assert a.estimated_bias_um == pytest.approx(3.0 * 4 / 4.25)
    assert a.bias_sigma_um == pytest.approx(math.sqrt(4 * 0.25 / 4.25))  # 0.485
    assert o.applied and a.bias_um == pytest.approx(3.0 * 4 / 4.25 - 4 * a.bias_sigma_um)
    assert a.bias_um == pytest.approx(0.883, abs=1e-3)
    assert a.correction_um([6.0, 4.0]) == a.bias_um
    refused = a.update(60.0, 10.0, [6.0, 4.0])
    assert not refused.accepted and refused.reason == "gate"


def test_a_precise_probe_is_taken_whole() -> None:
    """R/S below PRECISE_PROBE: the prediction meets the probe (the docstring's P = 25)."""
    a = Adapter(AdaptationParams(probe_noise_um=0.5, initial_bias_sigma_um=5.0,
                                 bias_rw_um_per_sqrt_h=5.0, max_step_um=10.0,
                                 apply_sigma=0.0), 1)
    o = a.update(13.0, 10.0, [0.0])
    assert o.accepted and PRECISE_PROBE > 0.25 / 25.25
    assert a.estimated_bias_um == 3.0 and a.correction_um([]) == 3.0
    assert a.bias_sigma_um == pytest.approx(0.5)  # Joseph form: (1 - 1)² P + 1² R
    # an error drifting 5 µm/√h probed hourly: the held residual at every probe (crude)
    for err in [4.0, 6.5, 9.0, 12.0]:
        a.advance(HOUR)
        a.update(10.0 + err, 10.0, [0.0])
        assert a.correction_um([]) == pytest.approx(err)
    # a noisy probe against a small uncertainty still averages (R/S above the share)
    b = Adapter(AdaptationParams(probe_noise_um=2.0, initial_bias_sigma_um=1.0), 1)
    b.update(3.0, 0.0, [0.0])
    assert b.estimated_bias_um == pytest.approx(3.0 * 1 / 5)


def test_bias_converges_on_a_constant_offset() -> None:
    a = Adapter(AdaptationParams(bias_rw_um_per_sqrt_h=0.2, probe_noise_um=0.5), 1)
    biases = _probe_run(a, [7.0] * 40, 2 * HOUR, 0.5, seed=1)
    assert abs(biases[-1] - 7.0) < 0.5
    assert a.bias_sigma_um < 0.5
    assert a.accepted == 40 and a.refused == 0


def test_bias_tracks_a_random_walk_better_than_the_last_probe() -> None:
    rng = np.random.default_rng(5)
    steps = rng.normal(0, 1.5, 400)  # 1.5 µm per √h, probed every hour
    truth = list(np.clip(np.cumsum(steps), -15, 15))
    a = Adapter(AdaptationParams(bias_rw_um_per_sqrt_h=1.5, probe_noise_um=2.0), 1)
    noisy_rng = np.random.default_rng(9)
    probes = [t + float(noisy_rng.normal(0, 2.0)) for t in truth]
    est = []
    for z in probes:
        a.advance(HOUR)
        a.update(z, 0.0, [0.0])
        est.append(a.estimated_bias_um)
    err_kf = np.sqrt(np.mean((np.array(est) - truth) ** 2))
    err_raw = np.sqrt(np.mean((np.array(probes) - truth) ** 2))
    assert err_kf < 0.8 * err_raw  # the filter averages the probe noise away
    assert err_kf < 2.0


def test_gate_refuses_a_50_um_outlier_and_keeps_state() -> None:
    a = Adapter(AdaptationParams(), 1)
    _probe_run(a, [3.0] * 10, 2 * HOUR, 0.5, seed=2)
    before = a.export_state()
    a.advance(2 * HOUR)
    o = a.update(3.0 + 50.0, 0.0, [0.0])
    assert not o.accepted and o.reason == "gate"
    assert abs(o.innovation_um) > 45 and abs(o.innovation_um) > 4 * o.innovation_sigma_um
    after = a.export_state()
    assert after["x"] == before["x"] and after["P"] == before["P"]
    assert a.refused == 1
    assert a.update(3.2, 0.0, [0.0]).accepted  # the next good probe is learnt


def test_non_finite_probe_is_a_fault_refusal() -> None:
    a = Adapter(AdaptationParams(), 1)
    o = a.update(math.nan, 0.0, [1.0])
    assert not o.accepted and o.reason == "fault" and a.bias_um == 0.0
    o = a.refuse("fault", 2.0, 1.0, [1.0])
    assert o.reason == "fault" and o.innovation_um == 1.0 and a.refused == 2


def test_steps_are_bounded_per_probe_and_in_total() -> None:
    p = AdaptationParams(bias_rw_um_per_sqrt_h=50.0, initial_bias_sigma_um=100.0,
                         gate_sigma=1e6, max_step_um=2.0, max_total_um=7.0, apply_sigma=0.0)
    a = Adapter(p, 1)
    biases = _probe_run(a, [30.0] * 10, HOUR, 0.1, seed=3)
    assert biases[:3] == pytest.approx([2.0, 4.0, 6.0])
    assert max(abs(b) for b in biases) == pytest.approx(7.0)


def test_gains_learn_a_gain_error_that_a_bias_cannot() -> None:
    # the model misses 20 % of term 1 which varies (0..10 µm); term 2 is right
    p = AdaptationParams(bias_rw_um_per_sqrt_h=0.1, gains=True, gain_rw_per_sqrt_h=0.01,
                         initial_gain_sigma=0.2, apply_sigma=0.0)
    a = Adapter(p, 2)
    rng = np.random.default_rng(4)
    for k in range(60):
        t1 = 5.0 + 5.0 * math.sin(k / 4)
        t2 = 3.0
        a.advance(HOUR)
        a.update(t1 * 1.2 + t2 + float(rng.normal(0, 0.3)), t1 + t2, [t1, t2])
    g1, g2 = a.gain_corrections
    assert g1 == pytest.approx(0.2, abs=0.05)
    assert a.correction_um([10.0, 3.0]) == pytest.approx(2.0, abs=0.5)
    assert abs(g2 * 3.0 + a.bias_um) < 0.5  # bias and term-2 gain not separable: sum ~ 0


def test_state_round_trips_through_json_and_behaves_the_same() -> None:
    p = AdaptationParams(gains=True)
    a = Adapter(p, 3)
    for k in range(5):
        a.advance(1000.0)
        a.update(2.0 + k * 0.1, 1.0, [1.0, 2.0, float(k)])
    a.advance(123.0)
    state = json.loads(json.dumps(a.export_state()))
    b = Adapter.from_state(p, 3, state)
    assert b.export_state() == a.export_state()
    for x in (a, b):
        x.advance(77.0)
    assert a.update(3.0, 1.0, [1, 2, 3]) == b.update(3.0, 1.0, [1, 2, 3])
    assert a.export_state() == b.export_state()


@pytest.mark.parametrize("change", [
    {"version": 99}, {"n_terms": 2}, {"gains": False}, {"x": [0.0]}, {"x": ["1", 0, 0, 0]},
    {"P": [[1.0, 2.0], [3.0, 4.0]]}, {"pending_s": -1.0}, {"accepted": -1},
    {"x": [1e9, 0.0, 0.0, 0.0]}, {"pending_s": math.nan}, {"refused": True},
    {"applied": [1e9, 0.0, 0.0, 0.0]}, {"applied": None}, {"applied_moves": -2},
    {"version": True},
])
def test_bad_state_is_a_value_error(change: dict[str, object]) -> None:
    p = AdaptationParams(gains=True)
    state = {**Adapter(p, 3).export_state(), **change}
    with pytest.raises(ValueError, match="adaptation state"):
        Adapter.from_state(p, 3, state)


def test_asymmetric_or_negative_covariance_is_refused() -> None:
    p = AdaptationParams(gains=True)
    good = Adapter(p, 1).export_state()
    for bad in ([[1.0, 0.5], [0.4, 1.0]], [[1.0, 0.0], [0.0, -1.0]]):
        with pytest.raises(ValueError, match="P is not"):
            Adapter.from_state(p, 1, {**good, "P": bad})


def test_bad_parameters_name_the_field() -> None:
    with pytest.raises(ValueError, match="probe_noise_um: must be > 0"):
        AdaptationParams(probe_noise_um=0.0)
    with pytest.raises(ValueError, match="bias_rw_um_per_sqrt_h: must be a finite"):
        AdaptationParams(bias_rw_um_per_sqrt_h=math.inf)
    assert AdaptationParams().problems() == {}
    with pytest.raises(ValueError, match="dt_s"):
        Adapter(AdaptationParams(), 1).advance(-1.0)
    with pytest.raises(ValueError, match="n_terms"):
        Adapter(AdaptationParams(), 0)


def test_correction_without_gains_ignores_the_terms() -> None:
    a = Adapter(AdaptationParams(), 2)
    a.update(2.0, 0.0, [1.0, 1.0])
    assert a.correction_um([]) == a.correction_um([5.0, 9.0]) == a.bias_um


# -- the applied correction is earned (apply_sigma) -------------------------------------------

def test_probe_noise_alone_never_moves_the_applied_correction() -> None:
    # a right model, probes of 0.5 µm noise every 2 h for 20 days: the estimate wanders,
    # the applied correction (what the machine gets) stays at 0
    a = Adapter(AdaptationParams(probe_noise_um=0.5), 1)
    estimates = []
    for z in np.random.default_rng(7).normal(0.0, 0.5, 240):
        a.advance(2 * HOUR)
        o = a.update(float(z), 0.0, [])
        assert o.accepted and not o.applied and o.bias_um == 0.0
        estimates.append(o.estimated_bias_um)
    assert a.correction_um([]) == 0.0 and a.applied_moves == 0
    assert max(abs(e) for e in estimates) > 0.1  # the filter did move; the output did not


def test_a_real_offset_is_applied_within_a_few_probes() -> None:
    a = Adapter(AdaptationParams(probe_noise_um=0.5), 1)
    rng = np.random.default_rng(3)
    for _ in range(12):  # a day at the noise floor: nothing applied
        a.advance(2 * HOUR)
        a.update(float(rng.normal(0.0, 0.5)), 0.0, [])
    assert a.bias_um == 0.0
    moved_at = []
    for k in range(12):  # then the machine is 2.5 µm off
        a.advance(2 * HOUR)
        if a.update(2.5 + float(rng.normal(0.0, 0.5)), 0.0, []).applied:
            moved_at.append(k)
    assert moved_at and moved_at[0] <= 4
    assert a.estimated_bias_um == pytest.approx(2.5, abs=0.6)
    band = 4 * a.bias_sigma_um  # the applied bias lags the estimate by at most the band
    assert 0.5 < a.bias_um <= a.estimated_bias_um and a.estimated_bias_um - a.bias_um <= band


def test_apply_sigma_zero_applies_every_accepted_estimate() -> None:
    a = Adapter(AdaptationParams(probe_noise_um=0.5, apply_sigma=0.0, gains=True), 2)
    rng = np.random.default_rng(2)
    for k in range(20):
        a.advance(HOUR)
        terms = [float(k % 5), 2.0]
        o = a.update(float(rng.normal(0.3, 0.5)), 0.0, terms)
        assert o.accepted and a.bias_um == a.estimated_bias_um == o.estimated_bias_um
        assert a.gain_corrections == a.estimated_gains


def test_a_version_1_state_resumes_with_the_estimate_applied() -> None:
    p = AdaptationParams()
    a = Adapter(p, 1)
    for z in (3.0, 3.2, 2.9):
        a.advance(HOUR)
        a.update(z, 0.0, [])
    state = a.export_state()
    old = {k: v for k, v in state.items() if k not in ("applied", "applied_moves")}
    b = Adapter.from_state(p, 1, {**old, "version": 1})
    assert b.bias_um == b.estimated_bias_um == a.estimated_bias_um
    assert b.export_state()["version"] == STATE_VERSION


# -- properties -------------------------------------------------------------------------------

finite = st.floats(-1e4, 1e4, allow_nan=False)
anything = st.one_of(finite, st.just(math.nan), st.just(math.inf), st.floats(-1e12, 1e12))
events = st.lists(st.tuples(st.floats(0, 20 * HOUR), anything, finite,
                            st.lists(finite, min_size=2, max_size=2)), max_size=25)
params = st.builds(
    AdaptationParams,
    bias_rw_um_per_sqrt_h=st.floats(0, 20), probe_noise_um=st.floats(0.01, 10),
    gate_sigma=st.floats(0.5, 1e3), max_step_um=st.floats(0.01, 20),
    max_total_um=st.floats(0.1, 50), gains=st.booleans(), gain_rw_per_sqrt_h=st.floats(0, 0.5),
    max_gain=st.floats(0.01, 1), initial_bias_sigma_um=st.floats(0.01, 50),
    initial_gain_sigma=st.floats(0.0, 1), apply_sigma=st.floats(0.0, 8.0))


@settings(max_examples=150, deadline=None)
@given(params, events)
def test_bounds_hold_and_covariance_stays_symmetric_positive(
        p: AdaptationParams, evs: list[tuple[float, float, float, list[float]]]) -> None:
    a = Adapter(p, 2)
    for dt, measured, model, terms in evs:
        before, was_down = a.correction_um(terms), a.standing_down
        a.advance(dt)
        o = a.update(measured, model, terms)
        change = a.correction_um(terms) - before
        if o.standing_down == was_down:  # standing down or resuming: the output stage's slew
            assert abs(change) <= p.max_step_um * (1 + 1e-9) + 1e-9
        assert abs(a.bias_um) <= p.max_total_um * (1 + 1e-12)
        assert all(abs(g) <= p.max_gain * (1 + 1e-12) for g in a.gain_corrections)
        assert o.accepted == (o.reason is None)
        assert o.accepted or change == 0.0
        cov = a.covariance()
        assert np.array_equal(cov, cov.T)
        assert float(np.min(np.linalg.eigvalsh(cov))) >= -1e-9 * float(np.max(np.abs(cov)))
        assert math.isfinite(a.bias_sigma_um)
    restored = Adapter.from_state(p, 2, json.loads(json.dumps(a.export_state())))
    assert restored.export_state() == a.export_state()
