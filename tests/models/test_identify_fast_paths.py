"""The identification's shortcuts give the model of the plain computation, to
the bit: lfilter's kernel called directly (`filter_kernel.filter_zi`,
`filter_kernel.lfilter_rest`, the kernel loaded without `scipy.signal`), the
output-error fit reusing the simulation it just made and its row weights
(`output_error.CACHE_BYTES`), `arx_fit` memoised on the data, and per-term-oe's
fold fits left out of a stage whose every final estimate is refused."""

from __future__ import annotations

import subprocess
import sys
from typing import Any

import numpy as np
import pytest
from scipy.signal import lfilter

from models.identify import blocks, estimators, filter_kernel, orders, output_error, structures
from models.identify.filter_kernel import filter_zi, lfilter_rest
from models.identify.output_error import OeModel
from models.identify.segments import Segments
from models.identify.structures import Selection, select_structure


def _record(seed: int = 4) -> tuple[np.ndarray, list[np.ndarray], Segments]:
    """Two records (the second starting warm) of three inputs through first-
    and second-order terms, plus noise."""
    rng = np.random.default_rng(seed)
    seg = Segments.from_lengths([1500, 1100])
    n = seg.total
    us = [np.repeat(rng.uniform(-2.0, 2.0, n // h + 1), h)[:n] for h in (120, 170, 260)]
    y = (seg.filter([0.2], [1.0, -0.95], us[0]) + seg.filter([-0.1], [1.0, -0.9], us[1])
         + seg.filter([0.01, 0.02], [1.0, -1.6, 0.64], us[2]))
    s, e = seg.bounds[1]
    y[s:e] += 1.5 * 0.97 ** np.arange(1, e - s + 1)
    return y + 0.03 * rng.standard_normal(n), us, seg


def _select(**kw: Any) -> Selection:
    y, us, seg = _record()
    return select_structure(y, us, na_range=(1, 2), nb_range=(1, 2), segments=seg,
                            radius=0.9999, **kw)


def _same(a: Selection, b: Selection) -> None:
    assert a.chosen.structure == b.chosen.structure and a.orders == b.orders
    assert a.notes == b.notes and a.initial == b.initial
    for x, y in zip(a.candidates, b.candidates, strict=True):
        assert x == y  # every field, the model's coefficients to the bit
        for r, q in zip(x.heldout_residuals, y.heldout_residuals, strict=True):
            assert np.array_equal(r, q)


def _plain(monkeypatch: pytest.MonkeyPatch) -> None:
    """lfilter itself, no cached simulation or weights, no memo of arx_fit."""
    monkeypatch.setattr(filter_kernel, "_linear_filter", None)
    monkeypatch.setattr(output_error, "CACHE_BYTES", -1)
    for module in (estimators, orders):  # the fold models and the ARX order search
        monkeypatch.setattr(module, "arx_fit",
                            lambda d, na, nb, train, iterations=0:
                            estimators._arx_fit(d, na, nb, train, iterations)[0])


def test_the_model_alone_is_the_fits_model() -> None:
    """`output_error_model` (the structure search's fits: no simulation after
    the fit) gives `fit_output_error`'s model, to the bit."""
    y, us, seg = _record()
    mask = np.ones(y.size, dtype=bool)
    mask[900:1400] = False
    for groups in ([(0, 1, 2)], [(0,), (1,), (2,)]):
        args = (y, us, [(0.1,), (0.0, 0.05), (0.02,)], [(1.0, -0.9)] * len(groups), groups)
        kw: dict[str, Any] = {"mask": mask, "segments": seg, "radius": 0.9999, "tol": 1e-4}
        model, _ = output_error.fit_output_error(*args, **kw)
        assert output_error.output_error_model(*args, **kw) == model


def test_filter_zi_is_lfilter_to_the_bit() -> None:
    rng = np.random.default_rng(1)
    for b, a in (([0.3], [1.0]), ([0.3, -0.2, 0.1], [1.0]), ([1.0], [1.0, -0.9]),
                 ([0.2, 0.1], [1.0, -1.5, 0.56]), ([0.5, 0.1, 0.3, 0.2], [1.0, -0.5])):
        bb, aa = np.array(b), np.array(a)
        x = rng.standard_normal(777)
        zi = rng.standard_normal(max(len(a), len(b)) - 1)
        want, zf_want = lfilter(bb, aa, x, zi=zi)
        got, zf = filter_zi(bb, aa, x, zi)
        assert np.array_equal(got, want) and np.array_equal(zf, zf_want)
        assert np.array_equal(lfilter_rest(bb, aa, x), lfilter(bb, aa, x))


def test_the_kernel_is_loaded_without_scipy_signal() -> None:
    """A fit loads lfilter's kernel from its extension file alone: importing all
    of `scipy.signal` costs about a second of CPU at every `compd fit`."""
    code = ("import sys; import models.identify.blocks, models.identify.segments, "
            "models.identify.structures; from models.identify import filter_kernel as k; "
            "print(k._linear_filter is not None, 'scipy.signal' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, timeout=120).stdout.split()
    assert out == ["True", "False"]


@pytest.mark.parametrize("streamed", [False, True])
def test_the_shortcuts_choose_the_model_of_the_plain_computation(
        monkeypatch: pytest.MonkeyPatch, streamed: bool) -> None:
    if streamed:  # several blocks, straddling the records
        monkeypatch.setattr(blocks, "BLOCK_ROWS", 700)
        monkeypatch.setattr(blocks, "STREAM_ROWS", 700)
    usable = np.ones(2600, dtype=bool)
    usable[:200] = False  # a --from window: a mask on every fit
    fast = _select(usable=usable)
    fast_every = _select()
    _plain(monkeypatch)
    _same(fast, _select(usable=usable))
    _same(fast_every, _select())


def test_per_term_folds_are_left_out_of_a_stage_that_fails(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Every model of order 2 or numerator length 2 refused: the stage at orders 1-2 fails
    whatever its folds validate, so per-term-oe is fitted there only on
    every row; the first-order stage is then that of a search at order 1."""
    calls: list[tuple[int, bool]] = []
    fit = output_error.output_error_model

    def counted(*a: Any, **kw: Any) -> Any:
        mask = kw.get("mask")
        calls.append((len(kw["groups"] if "groups" in kw else a[4]),
                      mask is None or bool(np.all(mask))))
        return fit(*a, **kw)

    monkeypatch.setattr(estimators, "output_error_model", counted)

    def veto(m: OeModel) -> str | None:
        return "order 2" if any(len(b) > 2 for b in m.dens) or any(
            len(a) > 1 for a in m.nums) else None

    sel = _select(veto=veto)
    assert sel.fallback and sel.orders == (1, 1)
    y, us, seg = _record()
    direct = select_structure(y, us, na_range=(1, 1), nb_range=(1, 1), segments=seg,
                              radius=0.9999, veto=veto)
    assert sel.chosen.model == direct.chosen.model
    assert sel.chosen.validation_fit_pct == direct.chosen.validation_fit_pct
    per_term = [every for groups, every in calls if groups == 3]
    # the failed stage: one per-term fit (every row); the first-order stage and the
    # direct search: one per fold and one on every row each
    folds = structures.DEFAULT_FOLDS
    assert per_term.count(False) == 2 * folds
    assert per_term.count(True) == 3


def test_the_textbook_model_keeps_no_simulation_of_every_row_per_fold() -> None:
    """The textbook ARX's folds are pooled from their held-out rows: its
    peak (9 arrays of the record's length here, 12 when each fold kept its
    simulation) has no simulation of every row per fold."""
    import tracemalloc

    from models.identify.structures import make_data
    from models.identify.textbook import textbook

    rng = np.random.default_rng(5)
    n = 200_000
    us = [np.repeat(rng.uniform(-2.0, 2.0, n // h + 1), h)[:n] for h in (900, 1300, 1700)]
    y = sum(lfilter([0.02 * (t + 1)], [1.0, -0.99], u) for t, u in enumerate(us))
    y = np.asarray(y) + 0.05 * rng.standard_normal(n)
    d = make_data(y, us, Segments.single(n), 1.0, 4, "forward")
    tracemalloc.start()
    try:
        got = textbook(d, us)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert got is not None
    row_arrays = peak / (8 * n)
    assert row_arrays < 11, f"peak {peak / 1e6:.0f} MB: {row_arrays:.1f} arrays of every row"


def test_the_heldout_residue_is_made_in_place_to_the_bit() -> None:
    """`_heldout` makes the residue in the simulation's own array and the
    displacement in the held-out rows' copy: the figures and arrays of the
    plain computation (y[val] - sim[val], a first-row array beside it), to the bit."""
    from models.identify.fold_scores import _heldout, _simulate
    from models.identify.structures import make_data

    y, us, seg = _record()
    d = make_data(y, us, seg, 0.9999, 4, "forward")
    models = [estimators.arx_fit(d, 1, 1, train) for train, _ in d.splits]
    held = _heldout(d, models)
    err = disp = 0.0
    blocks: list[np.ndarray] = []
    for m, (train, val) in zip(models, d.splits, strict=True):
        assert m is not None
        sim = _simulate(d, m, train, y, us, seg)
        resid = y[val] - sim[val]
        err += float(np.sum(resid ** 2))
        start = np.concatenate([np.full(int(val[s:e].sum()), y[s]) for s, e in seg.bounds])
        disp += float(np.sum((y[val] - start) ** 2))
        at = 0
        for s, e in seg.bounds:
            k = int(val[s:e].sum())
            if k:
                blocks.append(resid[at:at + k])
            at += k
    count = sum(int(v.sum()) for _, v in d.splits)
    assert held.rms == np.sqrt(err / count) and held.displacement_rms == np.sqrt(disp / count)
    assert len(held.residuals) == len(blocks)
    assert all(np.array_equal(a, b) for a, b in zip(held.residuals, blocks, strict=True))


class _CountingVeto:
    """A veto that counts what it refuses (as `compd fit`'s does), and asked
    ahead `quietly` does not."""

    def __init__(self) -> None:
        self.vetoed: list[str] = []

    def quietly(self, m: OeModel) -> str | None:
        if any(len(b) > 2 for b in m.dens) or any(len(a) > 1 for a in m.nums):
            return f"order 2 (den {len(m.dens[0]) - 1})"
        return None

    def __call__(self, m: OeModel) -> str | None:
        why = self.quietly(m)
        if why is not None:
            self.vetoed.append(why)
        return why


def test_a_stage_whose_every_final_is_refused_fits_no_fold(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Every final estimate of orders 1-2 refused (ridge at every λ alike): the
    stage fails without a fold fitted, with the selection, the notes and the
    veto's count of the search that fits its folds first."""
    veto = _CountingVeto()
    trained: list[bool] = []
    real = estimators._fold_models

    def counted(d: Any, na: int, nb: int, train: Any, *a: Any, **kw: Any) -> Any:
        trained.append(bool(np.all(train == d.every)))
        return real(d, na, nb, train, *a, **kw)

    monkeypatch.setattr(structures, "_fold_models", counted)
    fast = _select(veto=veto)
    fast_fits = list(trained)
    monkeypatch.setattr(structures, "_every_final_refused", lambda *a: None)
    plain_veto = _CountingVeto()
    trained.clear()
    plain = _select(veto=plain_veto)
    assert fast.fallback and fast.orders == (1, 1) and fast.notes[0].startswith("failed:")
    _same(fast, plain)
    assert veto.vetoed == plain_veto.vetoed
    folds = structures.DEFAULT_FOLDS
    # the failed stage: its finals alone; the first-order stage: its finals, then its folds
    assert fast_fits == [True, True] + [False] * folds
    assert trained == ([True] + [False] * folds) * 2


def test_a_private_kernel_that_answers_otherwise_is_not_used() -> None:
    """scipy's private kernel is taken only when it filters a known case as lfilter
    does: one that raises, or takes other arguments, or computes otherwise (a scipy
    that changed it) leaves lfilter itself to run."""
    from models.identify import filter_kernel

    def raises(*args: object) -> object:
        raise TypeError("another signature")

    def ignores_state(b: object, a: object, x: object, axis: int, zi: object = None) -> object:
        return x if zi is None else (x, zi)

    assert filter_kernel._answers_as_lfilter(None) is None
    assert filter_kernel._answers_as_lfilter(raises) is None
    assert filter_kernel._answers_as_lfilter(ignores_state) is None
    kernel = filter_kernel._load_kernel()
    assert filter_kernel._answers_as_lfilter(kernel) is kernel
