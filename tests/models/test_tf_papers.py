"""Every paper TF against independent computations and the scipy oracle."""

from __future__ import annotations

import math
from decimal import Decimal
from fractions import Fraction

import numpy as np
import pytest
from scipy.signal import lfilter

from models.errors import ModelError
from models.sensitivity import dc_gain_sensitivity
from models.tf import TransferFunction
from tests.models.paper_tfs import PAPER_TFS, REFERENCE

NAMES = sorted(PAPER_TFS)


def _decimals(text: str) -> int:
    e = Decimal(text).as_tuple().exponent
    assert isinstance(e, int)
    return max(0, -e)


@pytest.mark.parametrize("name", NAMES)
def test_dc_gain_matches_exact_rational_arithmetic(name: str) -> None:
    a, b = PAPER_TFS[name]
    num, den = sum(Fraction(x) for x in a), sum(Fraction(x) for x in b)
    tf = TransferFunction(a, b, name)
    if den == 0:  # ε_amb: 0/0 at z = 1; the gain is that of the reduced form
        assert num == 0 and tf.cancelled == [1]
        expected = Fraction("-0.0251") / (1 - Fraction("0.9985"))
    else:
        expected = num / den
    assert tf.dc_gain == pytest.approx(float(expected), rel=1e-15)
    ref_gain = REFERENCE[name][0]
    assert tf.dc_gain == pytest.approx(ref_gain, abs=0.5 * 10 ** -_decimals(str(ref_gain)) + 1e-12)


@pytest.mark.parametrize("name", NAMES)
def test_step_response_matches_lfilter_over_20000_samples(name: str) -> None:
    a, b = PAPER_TFS[name]
    tf = TransferFunction(a, b, name)
    u = np.ones(20_000)
    ours = tf.simulate(u)
    # the oracle runs the coefficients as printed; the reduced ε_amb is compared
    # against the oracle on the reduced form, and the unreduced one within 2e-8 µm
    oracle = lfilter(np.array(tf.num), np.array(tf.den), u)
    np.testing.assert_allclose(ours, oracle, rtol=1e-9, atol=0)
    full = lfilter(np.array([float(x) for x in a]), np.array([float(x) for x in b]), u)
    np.testing.assert_allclose(ours, full, rtol=1e-9, atol=2e-8)


@pytest.mark.parametrize("name", NAMES)
def test_step_response_matches_60_digit_reference(name: str) -> None:
    _, y100, y1000, y10000 = REFERENCE[name]
    tf = TransferFunction(*PAPER_TFS[name], name=name)
    y = tf.simulate(np.ones(10_001))
    for k, ref in ((100, y100), (1000, y1000), (10_000, y10000)):
        digits = _decimals(repr(ref))
        assert abs(y[k] - ref) <= 0.5 * 10 ** -digits + 1e-11, (name, k, y[k], ref)


def test_y0_is_a0_over_b0() -> None:
    tf = TransferFunction(["2.5", "1"], ["2", "-1"], "scaled")
    assert tf.step(1.0) == 1.25  # b0 = 2 normalised once at construction


def test_poles_and_time_constants_as_published() -> None:
    poles = {n: sorted(abs(p) for p in TransferFunction(*PAPER_TFS[n], name=n).poles)
             for n in NAMES}
    assert poles["eps_SP1"] == pytest.approx([0.6557, 0.95805, 0.99856], abs=5e-5)
    assert poles["eps_amb"] == pytest.approx([0.9985])  # the z = 1 pole was cancelled
    assert poles["eps_SP2"] == pytest.approx([0.99983])
    assert poles["eps1"][-1] == pytest.approx(0.999528, abs=5e-7)
    assert poles["eps1"][0] == pytest.approx(0.377, abs=5e-4)
    assert poles["eps2"][-1] == pytest.approx(0.9999614, abs=5e-8)
    assert poles["eps2"][0] == pytest.approx(0.677, abs=5e-4)
    tau = -1.0 / math.log(max(poles["eps_SP2"]))
    assert round(tau) == 5882


def test_eps_amb_reduced_form_stays_accurate_over_30_days() -> None:
    tf = TransferFunction(*PAPER_TFS["eps_amb"], name="eps_amb")
    assert tf.order == 1 and tf.cancelled == [1]
    k = np.arange(30 * 86_400)
    y = tf.simulate(np.ones(k.size))
    exact = -0.0251 / 0.0015 * (1.0 - 0.9985 ** (k + 1.0))
    assert float(np.max(np.abs(y - exact))) < 4e-4


def test_dc_gain_sensitivity_makes_the_printed_precision_visible() -> None:
    sp1 = dc_gain_sensitivity(TransferFunction(*PAPER_TFS["eps_SP1"], name="sp1"))
    assert not sp1.bounded and not sp1.well_determined
    assert "NOT determined" in sp1.describe()
    sp2 = dc_gain_sensitivity(TransferFunction(*PAPER_TFS["eps_SP2"], name="sp2"))
    assert sp2.low == pytest.approx(16.57, abs=0.01) and sp2.high == pytest.approx(18.79, abs=0.01)
    e2 = dc_gain_sensitivity(TransferFunction(*PAPER_TFS["eps2"], name="e2"))
    assert e2.low == pytest.approx(-35.27, abs=0.01) and e2.high == pytest.approx(-22.59, abs=0.01)
    e1 = dc_gain_sensitivity(TransferFunction(*PAPER_TFS["eps1"], name="e1"))
    assert e1.well_determined


def test_trailing_zero_digits_count_as_printed_precision() -> None:
    # "10.01220" is known to ±5e-6, "10.0122" only to ±5e-5
    with_zero = TransferFunction(["10.01220", "-9.9895457"], ["1", "-0.9"], "z")
    without = TransferFunction(["10.0122", "-9.9895457"], ["1", "-0.9"], "z")
    assert dc_gain_sensitivity(with_zero).first_order < dc_gain_sensitivity(without).first_order


def test_rounding_eps_sp1_to_four_digits_makes_an_integrator_that_is_refused() -> None:
    # docs/models.md §2: rounding the table to 4 significant digits turns ε_SP1 into an integrator
    a, b = ["-0.0337", "0.0332"], ["1", "-1.301", "-0.3263", "0.6273"]
    rounded = TransferFunction(a, b, "sp1_4digits", allow_unstable=True)
    assert math.isinf(rounded.dc_gain)
    assert not rounded.is_stable
    assert max(abs(p) for p in rounded.poles) == pytest.approx(1.0, abs=1e-9)
    with pytest.raises(ModelError, match="sp1_4digits: unstable"):
        TransferFunction(a, b, "sp1_4digits")
