"""Calibration diagnostics: cancelling terms and a flat verification window."""

from __future__ import annotations

import numpy as np
import pytest

from models import diagnostics
from models.diagnostics import cancelling_terms, flat_window, input_condition


def test_opposite_large_gains_on_correlated_inputs_are_flagged() -> None:
    rng = np.random.default_rng(0)
    a = np.cumsum(rng.normal(0.0, 0.05, 2000))
    b = a + rng.normal(0.0, 0.02, 2000)
    out = cancelling_terms(["t01", "t02"], [a, b], [-15.5, 23.6], output_span=20.0)
    assert len(out) == 1 and "'t01' and 't02' cancel" in out[0] and "condition number" in out[0]
    assert cancelling_terms(["t01", "t02"], [a, b], [5.0, 3.0], output_span=20.0) == []
    independent = rng.normal(0.0, 1.0, 2000)
    assert cancelling_terms(["t01", "x"], [a, independent], [-15.5, 23.6], 20.0) == []
    assert input_condition([a, b]) > 10.0 > input_condition([a, independent])


def test_a_flat_window_is_said_and_a_moving_one_is_not() -> None:
    t = np.linspace(0.0, 1.0, 500)
    moving = 20.0 * np.sin(6.0 * t)
    assert flat_window(moving, 0.3 * np.sin(50.0 * t)) is None
    warning = flat_window(0.5 * t, 0.2 * np.sin(50.0 * t))
    assert warning is not None and "spans only 0.5 µm" in warning


def _pair_of(message: str) -> tuple[set[str], str]:
    """The two term names and the correlation a cancelling-terms message names
    ("terms 'a' and 'b' cancel each other: ..." or "a and b cancel: ...")."""
    first, _, second = message.partition(" cancel")[0].removeprefix("terms ").partition(" and ")
    return {first.strip("'"), second.strip("'")}, message.partition("r = ")[2].partition(" ")[0]


def test_fit_selection_and_fits_warning_find_the_same_cancelling_pair() -> None:
    """`compd fit`'s warning (`cancelling_terms`) and its selection's rejection
    (`models.identify.checks.implausible`) share one test of cancelling terms:
    on inputs correlated above both thresholds they name the same pair and r,
    on uncorrelated inputs neither speaks."""
    from models.diagnostics import cancelling_pairs
    from models.identify.checks import CANCEL_R, implausible

    rng = np.random.default_rng(1)
    a = np.cumsum(rng.normal(0.0, 0.05, 4000))
    a = 3.0 * (a - a.min()) / np.ptp(a)  # a 3 K span
    correlated = a + rng.normal(0.0, 0.01, a.size)
    independent = 3.0 * rng.random(a.size)
    gains = [-15.5, 23.6]  # µm/K: 46 and 71 µm over 3 K, each beyond the 20 µm output
    dens = [[1.0, -0.9], [1.0, -0.9]]  # |p| = 0.9: fast against 4000 samples
    nums = [[0.1 * k] for k in gains]  # DC gain k
    for other, cancel in ((correlated, True), (independent, False)):
        names = ["t01", "t02" if cancel else "x"]
        warned = cancelling_terms(names, [a, other], gains, output_span=20.0)
        rejected = implausible(nums, dens, [a, other], names, output_span=20.0, samples=4000)
        pairs = cancelling_pairs([a, other], gains, 20.0, min_r=CANCEL_R)
        if cancel:
            assert len(pairs) == 1 and abs(pairs[0].r) >= CANCEL_R
            assert rejected is not None and len(warned) == 1
            assert _pair_of(warned[0]) == _pair_of(rejected) == (
                {"t01", "t02"}, f"{pairs[0].r:.3f}")
        else:
            assert pairs == [] and rejected is None
            assert not any("cancel" in w for w in warned)


def test_condition_of_long_inputs_comes_from_their_gram_blocks(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Past GRAM_ROWS rows the figure is the Gram matrix's, summed block by block:
    the SVD's to many digits, without the centred columns of every row stacked."""
    rng = np.random.default_rng(1)
    a = np.cumsum(rng.normal(0.0, 0.05, 5000))
    inputs = [a, a + rng.normal(0.0, 0.02, 5000), rng.normal(0.0, 1.0, 5000)]
    whole = input_condition(inputs)
    monkeypatch.setattr(diagnostics, "GRAM_ROWS", 700)
    assert input_condition(inputs) == pytest.approx(whole, rel=1e-9)


def test_correlation_of_long_inputs_is_corrcoefs_from_centred_block_sums(
        monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(2)
    a = np.cumsum(rng.normal(0.0, 0.05, 5000))
    b = 0.3 * a + rng.normal(0.0, 0.05, 5000)
    whole = diagnostics.correlation(a, b)
    assert whole == float(np.corrcoef(a, b)[0, 1])
    monkeypatch.setattr(diagnostics, "GRAM_ROWS", 700)
    assert diagnostics.correlation(a, b) == pytest.approx(whole, rel=1e-12)
