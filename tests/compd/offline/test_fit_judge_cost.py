"""What `compd fit`'s last word and its textbook cost: a ridge member is
re-estimated on each calibration less a block at its own penalty alone, not
at every one of the grid; the textbook is fitted before the selection, so
that its arrays and the candidates' held-out residues are never held at
once; held-out rows are pooled fold by fold (`models.identify.validate.Pooled`)."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pytest

from compd.offline import fit_hedge, fit_judge, fit_select
from compd.offline.fit_judge import Member
from compd.offline.fit_request import FitRequest, FitRun
from models.identify import estimators, structures
from models.identify import textbook as textbook_mod
from models.identify.segments import Segments
from models.identify.structures import make_data, select_structure
from models.identify.validate import Pooled, pooled_parts
from tests.models.two_term_plant import two_term_plant

FloatArray = npt.NDArray[np.float64]




def test_a_ridge_member_is_refitted_at_its_own_penalty_alone(
        monkeypatch: pytest.MonkeyPatch) -> None:
    y, us = two_term_plant()
    seg = Segments.single(y.size)
    sel = select_structure(y, us, na_range=(1, 1), nb_range=(1, 1), segments=seg)
    cand = next(c for c in sel.candidates if c.structure == "ridge")
    member = Member(cand.structure, tuple(us), cand.model, sel.initial, cand.detail)
    block = np.zeros(y.size, dtype=bool)
    block[600:900] = True
    train = ~block
    chain = _chain(y, seg, member, train)
    lams: list[float] = []
    real = structures._ridge

    def ridge(d: object, shared: object, rows: object, lam: float) -> object:
        lams.append(lam)
        return real(d, shared, rows, lam)  # type: ignore[arg-type]

    monkeypatch.setattr(estimators, "_ridge", ridge)
    again = fit_judge.refit(y, seg, 1.0, None, member, train)
    assert lams == [float(cand.detail.rpartition("= ")[2])]  # not every λ of the grid
    assert again is not None and np.array_equal(again, chain)  # the same estimate, to the bit


def _chain(y: FloatArray, seg: Segments, member: Member, train: npt.NDArray[np.bool_]
           ) -> FloatArray:
    """`member` on `train` by the selection's chain (ARX, Steiglitz–McBride,
    shared-oe, ridge at every λ), run from the start."""
    d = structures._Data(y, list(member.us), seg, 1.0, [], initial=member.initial)
    na, nb = len(member.model.dens[0]) - 1, len(member.model.nums[0])
    key = "ridge:" + member.detail.rpartition("= ")[2]
    m = structures._fold_models(d, na, nb, train, (member.structure,), 40)[key]
    assert m is not None
    return structures._simulate(d, m, train, y, d.us, seg)


def test_the_textbook_is_fitted_before_the_selection(
        monkeypatch: pytest.MonkeyPatch) -> None:
    y, us = two_term_plant()
    seg = Segments.single(y.size)
    order: list[str] = []
    real_tb, real_sel = textbook_mod.textbook, structures.select_structure

    def tb(*a: object, **k: object) -> object:
        order.append("textbook")
        return real_tb(*a, **k)  # type: ignore[arg-type]

    def sel(*a: object, **k: object) -> object:
        order.append("selection")
        return real_sel(*a, **k)  # type: ignore[arg-type]

    monkeypatch.setattr(fit_hedge, "textbook", tb)
    monkeypatch.setattr(fit_select, "select_structure", sel)
    run = FitRun.of(FitRequest(data=("x.csv",), output="dz_um", term=("a", "b"),
                               orders=(1, 1)))
    specs = [("a", {"a": 1.0}), ("b", {"b": 1.0})]
    _terms, summary = fit_select.select_for_fit(run, y, us, seg, 1.0, None, specs,
                                                [True, True])
    assert order == ["textbook", "selection"]
    assert any(c["structure"] == "textbook" for c in summary["candidates"])


def test_the_textbook_lays_no_blocked_folds() -> None:
    y, us = two_term_plant(400)
    seg = Segments.single(y.size)
    assert make_data(y, us, seg, 1.0, 4, "forward").blocked is not None
    assert make_data(y, us, seg, 1.0, 4, "forward", blocked=False).blocked is None


def test_held_out_rows_pooled_fold_by_fold_give_the_same_figure() -> None:
    rng = np.random.default_rng(2)
    held = [(rng.standard_normal(50), rng.standard_normal(50)) for _ in range(4)]
    pool = Pooled()
    for y_m, sim_m in held:
        pool.add(y_m, sim_m)
    assert pool.value == pooled_parts(held)
    pool.add(np.ones(3), np.array([1.0, math.nan, 1.0]))
    assert pool.value == -math.inf


def test_held_out_residues_are_slices_of_one_array_per_fold() -> None:
    y, us = two_term_plant(1200)
    seg = Segments.from_lengths([500, 700])
    d = make_data(y, us, seg, 1.0, 4, "forward")
    d.initial = False
    models = [structures.arx_fit(d, 1, 1, train) for train, _ in d.splits]
    held = structures._heldout(d, models)
    assert len(held.residuals) == 2 * len(d.splits)  # a block per fold and record
    for k, ((train, val), m) in enumerate(zip(d.splits, models, strict=True)):
        assert m is not None
        sim = structures._simulate(d, m, train, y, d.us, seg)
        first, second = held.residuals[2 * k], held.residuals[2 * k + 1]
        for r, (s, e) in zip((first, second), seg.bounds, strict=True):
            rows = np.flatnonzero(val[s:e]) + s
            assert np.array_equal(r, y[rows] - sim[rows])  # the residue, to the bit
        # one array of the fold's held-out rows, not a copy per record
        assert first.base is not None and first.base is second.base


@pytest.mark.parametrize("structure", ["shared-oe", "ridge", "arx"])
def test_a_block_whose_calibration_is_a_fold_takes_the_selections_estimate(
        monkeypatch: pytest.MonkeyPatch, structure: str) -> None:
    """The end block's calibration is the last forward fold's: the verdict takes
    the selection's estimate there (no chain run again), the very run the
    chain gives; on any other rows it runs the chain."""
    y, us = two_term_plant()
    seg = Segments.single(y.size)
    sel = select_structure(y, us, na_range=(1, 1), nb_range=(1, 1), segments=seg)
    cand = next(c for c in sel.candidates if c.structure == structure)
    assert len(cand.fold_models) == len(make_data(y, us, seg, 1.0, 4, "forward").splits)
    member = Member(cand.structure, tuple(us), cand.model, sel.initial, cand.detail,
                    cand.fold_models)
    bare = Member(cand.structure, tuple(us), cand.model, sel.initial, cand.detail)
    last_fold = make_data(y, us, seg, 1.0, 4, "forward").splits[-1][0]
    other = np.ones(y.size, dtype=bool)
    other[600:900] = False
    chains: list[str] = []

    def counted(name: str) -> object:
        real = getattr(estimators, name)

        def run(*a: object, **k: object) -> object:
            chains.append(name)
            return real(*a, **k)
        return run

    want = fit_judge.refit(y, seg, 1.0, None, bare, last_fold)
    for name in ("_fold_models", "arx_fit"):
        monkeypatch.setattr(estimators, name, counted(name))
    got = fit_judge.refit(y, seg, 1.0, None, member, last_fold)
    assert want is not None and got is not None and np.array_equal(got, want)
    assert chains == []
    again = fit_judge.refit(y, seg, 1.0, None, member, other)
    assert chains  # rows of no fold: the chain runs
    plain = fit_judge.refit(y, seg, 1.0, None, bare, other)
    assert again is not None and plain is not None and np.array_equal(again, plain)
