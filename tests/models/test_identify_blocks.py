"""The identification over blocks of rows (`models.identify.blocks`): filters
and lags carried across blocks give the very numbers of one pass, a fit over
many blocks the figures of one block, and the output-error fit holds a few
rows' worth of arrays, not its Jacobian over every row."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest
from scipy.signal import lfilter

from models.identify import blocks
from models.identify.blocks import SegFilter, SegLags, row_blocks, solve_blocks, solve_one
from models.identify.output_error import fit_output_error
from models.identify.segments import Segments
from models.identify.structures import select_structure


def _steps(rng: np.random.Generator, n: int, hold: int) -> np.ndarray:
    return np.repeat(rng.uniform(-2.0, 2.0, n // hold + 1), hold)[:n]


def _records(lengths: tuple[int, ...], seed: int = 0) -> tuple[np.ndarray, list[np.ndarray],
                                                                Segments]:
    """Two inputs through 0.2/(1 - 0.95 q⁻¹) and -0.1/(1 - 0.9 q⁻¹), each record
    starting warm, plus noise."""
    rng = np.random.default_rng(seed)
    seg = Segments.from_lengths(list(lengths))
    n = seg.total
    us = [_steps(rng, n, 150), _steps(rng, n, 230)]
    y = seg.filter([0.2], [1.0, -0.95], us[0]) + seg.filter([-0.1], [1.0, -0.9], us[1])
    for s, e in seg.bounds:
        y[s:e] += 2.0 * 0.95 ** np.arange(1, e - s + 1) + 1.0
    return y + 0.05 * rng.standard_normal(n), us, seg


def test_filters_and_lags_over_blocks_are_the_numbers_of_one_pass() -> None:
    seg = Segments.from_lengths([5, 700, 3, 1100])
    x = np.random.default_rng(1).standard_normal(seg.total)
    for size in (1, 4, 97, 512, 4096):
        filt = SegFilter(seg, [0.3, -0.1], [1.0, -1.7, 0.72])
        lags = SegLags(seg, 3)
        got = np.concatenate([filt(x[lo:hi], lo) for lo, hi in row_blocks(seg.total, size)])
        assert np.array_equal(got, seg.filter([0.3, -0.1], [1.0, -1.7, 0.72], x))
        for d in range(4):
            parts = []
            for lo, hi in row_blocks(seg.total, size):
                lags.feed(got[lo:hi], lo)
                parts.append(lags.shift(d))
            assert np.array_equal(np.concatenate(parts), seg.shift(got, d))
            lags = SegLags(seg, 3)


def test_normal_equations_over_blocks_solve_as_one_block() -> None:
    rng = np.random.default_rng(2)
    a = rng.standard_normal((5000, 6)) * [1.0, 10.0, 1e3, 0.1, 1.0, 5.0]
    b = a @ [1.0, -2.0, 3e-3, 40.0, 0.5, 0.0] + 0.01 * rng.standard_normal(5000)
    one = solve_blocks([(a, b)])
    assert np.array_equal(one, solve_one(a, b))  # one block: the very call
    many = solve_blocks((a[lo:hi], b[lo:hi]) for lo, hi in row_blocks(5000, 333))
    np.testing.assert_allclose(many, one, rtol=1e-9, atol=1e-12)


def test_structure_choice_over_many_blocks_is_that_of_one(monkeypatch: pytest.MonkeyPatch
                                                          ) -> None:
    y, us, seg = _records((2400, 1800))
    kwargs = {"na_range": (1, 2), "nb_range": (1, 2), "segments": seg, "radius": 0.9999}
    whole = select_structure(y, us, **kwargs)  # type: ignore[arg-type]
    monkeypatch.setattr(blocks, "BLOCK_ROWS", 700)  # several blocks, straddling the records
    monkeypatch.setattr(blocks, "STREAM_ROWS", 700)
    blocked = select_structure(y, us, **kwargs)  # type: ignore[arg-type]
    assert blocked.chosen.structure == whole.chosen.structure
    assert blocked.orders == whole.orders and blocked.initial == whole.initial
    for got, want in zip(blocked.candidates, whole.candidates, strict=True):
        assert got.structure == want.structure
        assert got.validation_fit_pct == pytest.approx(want.validation_fit_pct, abs=1e-6)
        for a, b in zip(got.model.nums + got.model.dens, want.model.nums + want.model.dens,
                        strict=True):
            np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("cache", [False, True])
def test_output_error_holds_no_jacobian_of_every_row(monkeypatch: pytest.MonkeyPatch,
                                                     cache: bool) -> None:
    """Four inputs, per-term denominators of order 2, numerators of 3, initial
    conditions: 25 parameters. Its Jacobian over every row is 25 arrays of
    the record's length; the fit now holds a handful (the residue, the
    weights, a simulation) beside blocks of `STREAM_ROWS` rows, and, while
    it fits within `CACHE_BYTES`, the last simulation's inputs and outputs
    (4 + 4 + 1 arrays here)."""
    from models.identify import output_error

    if not cache:
        monkeypatch.setattr(output_error, "CACHE_BYTES", 0)
    n = 200_000
    rng = np.random.default_rng(3)
    us = [_steps(rng, n, h) for h in (900, 1300, 1700, 2100)]
    y = sum(lfilter([0.02 * (t + 1)], [1.0, -0.99], u) for t, u in enumerate(us))
    y = np.asarray(y) + 0.05 * rng.standard_normal(n)
    monkeypatch.setattr(blocks, "STREAM_ROWS", 8192)
    nums = [(0.01, 0.0, 0.0)] * 4
    dens = [(1.0, -1.5, 0.55)] * 4
    tracemalloc.start()
    try:
        fit_output_error(y, us, nums, dens, [(t,) for t in range(4)], initial=True,
                         max_iter=2)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    row_arrays = peak / (8 * n) - (9 if cache else 0)
    assert row_arrays < 10, f"peak {peak / 1e6:.0f} MB: {row_arrays:.1f} arrays of every row"


def test_initial_state_over_a_long_window_is_that_of_one_least_squares(
        monkeypatch: pytest.MonkeyPatch) -> None:
    from models import initial_state

    rng = np.random.default_rng(4)
    n = 6000
    basis = np.stack([np.ones(n), 0.999 ** np.arange(n), 0.99 ** np.arange(n)], axis=1)
    residual = basis @ [0.5, -3.0, 2.0] + 0.01 * rng.standard_normal(n)
    whole = initial_state.estimate_initial_state(residual, basis, ["a", "b"], 4000)
    monkeypatch.setattr(initial_state, "GRAM_ROWS", 700)
    blocked = initial_state.estimate_initial_state(residual, basis, ["a", "b"], 4000)
    assert blocked.offset_um == pytest.approx(whole.offset_um, rel=1e-8)
    for name in ("a", "b"):
        assert blocked.levels[name] == pytest.approx(whole.levels[name], rel=1e-8)
