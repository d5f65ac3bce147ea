"""Identification numerics: ARX order search, output-error refinement, grey-box and
MBOTV fits, each checked against the model classes the daemon steps."""

from __future__ import annotations

import numpy as np
import pytest

from models.greybox import GreyBox
from models.identify.arx import naive_select, select_arx, simulate_common
from models.identify.greybox_fit import fit_greybox, simulate_greybox
from models.identify.mbotv_fit import fit_mbotv, simulate_mbotv
from models.identify.output_error import refine_oe
from models.identify.reflection import step_down, step_up
from models.identify.tf_fit import fit_tf_terms
from models.mbotv import Mbotv
from models.tf import TransferFunction


def _steps(n: int, seed: int, hold: int = 400) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.repeat(rng.uniform(-3.0, 3.0, n // hold + 1), hold)[:n]


def test_step_up_and_down_are_inverse_and_bound_stability() -> None:
    den = [1.0, -1.2, 0.5, -0.1]
    kappa = step_down(den)
    assert np.all(np.abs(kappa) < 1.0)
    np.testing.assert_allclose(step_up(kappa), den, atol=1e-14)
    unstable = step_up([0.5, -0.999999])
    assert np.all(np.abs(np.roots(unstable)) < 1.0)


def test_arx_recovers_a_noise_free_two_input_model_and_matches_the_naive_loop() -> None:
    n = 6000
    u1, u2 = _steps(n, 1), _steps(n, 2, hold=700)
    den, nums = (1.0, -0.95), ((0.5, -0.3), (0.2,))
    y = simulate_common(den, nums, [u1, u2])
    est, cands = select_arx(y, [u1, u2], (1, 3), (1, 3))
    assert est.na == 1 and est.nbs == (2, 1)
    np.testing.assert_allclose(est.den, den, atol=1e-9)
    np.testing.assert_allclose(est.nums[0], nums[0], atol=1e-9)
    naive = naive_select(y, [u1, u2], (1, 3), (1, 3))
    assert len(naive) == len(cands) == 27
    for a, b in zip(cands, naive, strict=True):
        assert (a.na, a.nbs) == (b.na, b.nbs)
        assert a.validation_fit_pct == pytest.approx(b.validation_fit_pct, abs=0.05)


def test_output_error_removes_the_arx_noise_bias() -> None:
    n = 20000
    rng = np.random.default_rng(5)
    u = _steps(n, 3, hold=1500)
    tf = TransferFunction([4.30702, -4.28923], [1, -0.9984])
    y_true = tf.simulate(u)
    y = y_true + 0.5 * rng.standard_normal(n)
    fit = fit_tf_terms(y, [u], (1, 3), (1, 3))
    num, den = fit.oe.nums[0], fit.oe.dens[0]
    assert sum(num) / sum(den) == pytest.approx(tf.dc_gain, rel=0.02)
    assert fit.oe.fit_pct > fit.arx_fit_pct
    assert fit.orders == ((2, 1),)
    oe = refine_oe(y, [u], fit.oe.nums, fit.oe.dens)  # a second pass stays put
    assert oe.fit_pct == pytest.approx(fit.oe.fit_pct, abs=1e-6)


@pytest.mark.parametrize("switched", [False, True])
def test_greybox_fit_recovers_parameters_and_simulates_like_the_daemon(switched: bool) -> None:
    period = 10.0
    n = 8000
    power = np.abs(_steps(n, 7, hold=300)) * 2.0
    moving = (power > 1.5).astype(np.float64) if switched else None
    p = [-2e-4, 3e-4, 0.1] + ([-1e-4, 1e-4, 0.0] if switched else [])
    gb = GreyBox(p, period)
    u2 = moving if moving is not None else np.ones(n)
    y_true = np.array([gb.step(float(a), float(b)) for a, b in zip(power, u2, strict=True)])
    np.testing.assert_allclose(simulate_greybox(np.array(p), period, power, moving), y_true,
                               rtol=1e-9, atol=1e-9)
    fit = fit_greybox(y_true, power, period, moving)
    assert fit.fit_pct > 99.0
    assert -fit.p[1] / fit.p[0] == pytest.approx(-p[1] / p[0], rel=0.02)


def test_mbotv_fit_recovers_parameters_and_simulates_like_the_daemon() -> None:
    period = 10.0
    T = np.cumsum(_steps(6000, 9, hold=200)) * 0.01
    m = Mbotv.from_tau(alpha=3.0, beta=40.0, tau_s=1800.0, gamma=0.8, period_s=period)
    x = np.array([3.0, 40.0, 0.0, m.k, 0.8])
    y = np.array([m.step(float(t)) for t in T])
    np.testing.assert_allclose(simulate_mbotv(x, period, T), y, rtol=1e-9, atol=1e-9)
    fit = fit_mbotv(y, T, period)
    assert fit.alpha == pytest.approx(3.0, rel=0.02)
    assert fit.fit_pct > 99.0


def test_segments_restart_every_record_from_rest() -> None:
    from models.identify.arx import refit
    from models.identify.segments import Segments

    seg = Segments.from_lengths([3, 2])
    assert seg.bounds == ((0, 3), (3, 5))
    np.testing.assert_array_equal(seg.shift(np.arange(1.0, 6.0), 1), [0, 1, 2, 0, 4])
    # two records fitted jointly == the same model simulated on each alone
    u1, u2 = _steps(3000, 11), _steps(2000, 12, hold=300)
    tf = TransferFunction([0.5, -0.3], [1, -0.95])
    y = np.concatenate([tf.simulate(u1), tf.simulate(u2)])
    joint = refit(y, [np.concatenate([u1, u2])], 1, [2],
                  segments=Segments.from_lengths([3000, 2000]))
    np.testing.assert_allclose(joint.den, [1, -0.95], atol=1e-9)
    np.testing.assert_allclose(joint.nums[0], [0.5, -0.3], atol=1e-9)


def test_output_error_keeps_every_pole_within_the_radius() -> None:
    from models.identify.segments import Segments, pole_radius

    assert pole_radius(10.0, 3 * 86400.0) == pytest.approx(0.9999614, abs=1e-7)
    n = 4000
    u = _steps(n, 13, hold=500)
    y = TransferFunction([0.01], [1, -0.999]).simulate(u)  # τ ≈ 1000 samples
    radius = 0.99
    est = refine_oe(y, [u], [[0.01]], [[1.0, -0.999]], radius=radius,
                    segments=Segments.single(n))
    assert np.max(np.abs(np.roots(est.dens[0]))) < radius


def test_checks_refuse_a_slow_pole_and_an_absurd_dc_gain() -> None:
    from models.errors import ModelError
    from models.identify.checks import build_checked_tf

    with pytest.raises(ModelError, match="time constant"):
        build_checked_tf([1e-6], [1.0, -(1.0 - 1e-12)], "ambient", max_pole=0.9999,
                         period_s=10.0)
    with pytest.raises(ModelError, match="implausible steady state"):
        build_checked_tf([1e-2], [1.0, -0.99999], "ambient", input_span=6.0, output_span=20.0)
    ok = build_checked_tf([0.5, -0.3], [1.0, -0.95], "spindle", max_pole=0.99,
                          input_span=10.0, output_span=40.0)
    assert ok.dc_gain == pytest.approx(4.0)
