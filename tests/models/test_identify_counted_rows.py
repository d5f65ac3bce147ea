"""A fit over some rows filters nothing past the last row it counts: output
error's simulation and Jacobian, the ARX / Steiglitz–McBride and ridge
regressors stop there (the filters are causal, so every row before is the
same to the bit). A forward fold trains on a record's beginning: the rest of
the record is never filtered for it."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pytest

from models.identify import blocks as blocks_mod
from models.identify import fold_scores
from models.identify import output_error as oe
from models.identify.blocks import BLOCK_ROWS, STREAM_ROWS, SegFilter, row_blocks
from models.identify.estimators import _arx_blocks, _ridge, arx_fit
from models.identify.filter_kernel import filter_zi
from models.identify.fold_data import make_data
from models.identify.output_error import counted_end, output_error_model
from models.identify.segments import Segments
from models.identify.structures import select_structure
from tests.models.two_term_plant import two_term_plant

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]




def _nan_after(x: FloatArray, end: int) -> FloatArray:
    out = x.copy()
    out[end:] = np.nan
    return out


def _filtered_ends(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """One past the last row of every `SegFilter` call from now on."""
    ends: list[int] = []
    real = SegFilter.__call__

    def call(self: SegFilter, x: FloatArray, lo: int) -> FloatArray:
        ends.append(lo + x.size)
        return real(self, x, lo)

    monkeypatch.setattr(SegFilter, "__call__", call)
    return ends


def test_counted_end_is_one_past_the_last_row_of_the_mask() -> None:
    mask = np.zeros(10, dtype=bool)
    assert counted_end(mask) == 0
    mask[[2, 6]] = True
    assert counted_end(mask) == 7
    mask[9] = True
    assert counted_end(mask) == 10
    assert counted_end(np.zeros(0, dtype=bool)) == 0


@pytest.mark.parametrize("per_term", [False, True])
def test_output_error_on_a_prefix_never_sees_the_rows_after_it(
        monkeypatch: pytest.MonkeyPatch, per_term: bool) -> None:
    """NaN in every row past the mask's last one changes no bit of the estimate
    (a weight 0 times NaN is NaN: those rows were simulated before), and no
    filter runs past it."""
    y, us = two_term_plant()
    end = 600
    mask = np.zeros(y.size, dtype=bool)
    mask[:end] = True
    groups = [(0,), (1,)] if per_term else [(0, 1)]
    dens = [(1.0, -0.98)] * len(groups)
    nums = [(0.05,), (-0.02,)]
    clean = output_error_model(y, us, nums, dens, groups, mask=mask, tol=1e-9)
    ends = _filtered_ends(monkeypatch)
    dirty = output_error_model(_nan_after(y, end), [_nan_after(u, end) for u in us], nums, dens,
                               groups, mask=mask, tol=1e-9)
    assert dirty == clean
    assert ends and max(ends) == end
    assert all(np.isfinite(v) for a in clean.nums for v in a)


def test_steiglitz_mcbride_and_ridge_on_a_prefix_filter_nothing_after_it(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A forward fold's least squares: the estimates of a record whose rows after
    the fold's last training row are NaN are those of the clean record, bit for
    bit, and no filter call reaches past that row."""
    y, us = two_term_plant()
    seg = Segments.single(y.size)
    train = np.zeros(y.size, dtype=bool)
    train[:700] = True
    clean = make_data(y, us, seg, 1.0, 4, "forward")
    sm = arx_fit(clean, 1, 2, train, 4)
    assert sm is not None
    ridge = _ridge(clean, sm, train, 1e-3)
    ends = _filtered_ends(monkeypatch)
    dirty = make_data(_nan_after(y, 700), [_nan_after(u, 700) for u in us], seg, 1.0, 4,
                      "forward")
    assert arx_fit(dirty, 1, 2, train, 4) == sm
    assert _ridge(dirty, sm, train, 1e-3) == ridge
    assert ends and max(ends) == 700


def test_a_streamed_record_keeps_its_blocks_past_the_last_row(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Past `BLOCK_ROWS` rows the regressors come in blocks, their normal
    equations summed: a block after the last training row is still handed on
    (empty), so the sums are taken as over the whole record, and nothing in it
    is filtered."""
    n = BLOCK_ROWS + 1000
    rng = np.random.default_rng(3)
    u = np.cumsum(rng.standard_normal(n)) * 0.01
    y = np.convolve(u, [0.5, 0.3])[:n] + 0.01 * rng.standard_normal(n)
    seg = Segments.single(n)
    d = make_data(y, [u], seg, 1.0, 4, "forward", blocked=False)
    rows = np.zeros(n, dtype=bool)
    rows[5:STREAM_ROWS + 100] = True
    ends = _filtered_ends(monkeypatch)
    got = list(_arx_blocks(d, y, 1, 2, 1, (1.0, -0.5), rows))
    assert len(got) == len(list(row_blocks(n)))
    assert [a.shape[0] for a, _ in got[:2]] == [STREAM_ROWS - 5, 100]
    assert all(a.shape == (0, got[0][0].shape[1]) and b.size == 0 for a, b in got[2:])
    assert max(ends) == STREAM_ROWS + 100


def _problem(n: int, nbs: tuple[int, ...], initial: bool) -> tuple[oe._Problem, FloatArray]:
    rng = np.random.default_rng(11)
    us = [np.cumsum(rng.standard_normal(n)) * 0.01 for _ in nbs]
    y = 0.4 * us[0] + 0.01 * rng.standard_normal(n)
    seg = Segments.from_lengths([n // 3, n - n // 3])
    prob = oe._Problem(y, us, list(nbs), [2], [tuple(range(len(nbs)))], seg, 1.0, initial)
    th = np.concatenate([rng.uniform(-0.2, 0.2, sum(nbs)), [0.9, -0.3],
                         rng.uniform(-1.0, 1.0, prob.n_init)])
    return prob, th


@pytest.mark.parametrize(("n", "cut"), [
    (3000, 1700),  # one block, cut inside the second record
    (BLOCK_ROWS + 10, STREAM_ROWS),  # streamed, cut at a block's end: the lags reach past it
    (BLOCK_ROWS + 10, 2 * STREAM_ROWS - 1),  # ... one row before a block's end
])
@pytest.mark.parametrize("initial", [False, True])
def test_the_residual_and_normal_equations_are_those_of_every_row_to_the_bit(
        monkeypatch: pytest.MonkeyPatch, n: int, cut: int, initial: bool) -> None:
    """Stopping at the mask's last row changes no bit of the residual, JᵀJ or Jᵀr
    (each simulated over every row when the end is not looked for), a hole in
    the mask included; a numerator's lagged Jacobian rows lag the weighed row,
    so they reach nb - 1 rows past the last counted one, into the next block."""
    prob, th = _problem(n, (3, 1), initial)
    mask = np.zeros(n, dtype=bool)
    mask[:cut] = True
    mask[cut // 4:cut // 3] = False
    r = prob.residual(th, mask)
    got = prob.normal_equations(th, mask, r)
    every, _ = _problem(n, (3, 1), initial)
    monkeypatch.setattr(oe, "counted_end", lambda m: m.size)
    r_all = every.residual(th, mask)
    want = every.normal_equations(th, mask, r_all)
    assert np.array_equal(r, r_all)
    assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])
    assert np.all(np.isfinite(got[0]))


@pytest.mark.parametrize("initial", [False, True])
@pytest.mark.parametrize("n", [1500, BLOCK_ROWS + 10])
def test_a_fold_is_simulated_to_the_end_of_its_held_out_rows_only(
        monkeypatch: pytest.MonkeyPatch, initial: bool, n: int) -> None:
    """A forward fold's score reads its held-out block: the model is simulated
    (initial conditions fitted on the training rows) up to that block's end,
    each row there the same to the bit as in the run over every row."""
    rng = np.random.default_rng(4)
    us = [np.cumsum(rng.standard_normal(n)) * 0.01 for _ in range(2)]
    y = 0.3 * us[0] - 0.2 * us[1] + 0.01 * rng.standard_normal(n)
    seg = Segments.from_lengths([n // 4, n - n // 4])
    d = make_data(y, us, seg, 1.0, 4, "forward", blocked=False)
    d.initial = initial
    m = oe.OeModel(nums=((0.05, 0.01), (-0.03, 0.0)), dens=((1.0, -0.9),), groups=((0, 1),))
    train, val = d.splits[1]
    end = counted_end(val)
    assert end < n
    whole = fold_scores._simulate(d, m, train, y, us, seg)
    ends = _filtered_ends(monkeypatch)
    part = fold_scores._simulate(d, m, train, y, us, seg, val)
    assert np.array_equal(part[:end], whole[:end])
    assert max(ends) == end


def test_a_structure_search_filters_within_its_budget_of_rows(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The rows every filter of a structure search runs over, counted on a small
    record (orders 1-2, four forward folds): 841,200, where filtering each
    fold's fits and scores through the whole record took 1,302,000."""
    y, us = two_term_plant()
    rows = [0]
    real = filter_zi

    def counted(b: FloatArray, a: FloatArray, x: FloatArray, zi: FloatArray
                ) -> tuple[FloatArray, FloatArray]:
        rows[0] += x.size
        return real(b, a, x, zi)

    monkeypatch.setattr(blocks_mod, "filter_zi", counted)
    sel = select_structure(y, us, na_range=(1, 2), nb_range=(1, 2),
                           segments=Segments.single(y.size))
    assert sel.chosen.structure == "per-term-oe"
    assert rows[0] <= 900_000
