"""Model structures for a set of inputs, chosen by forward validation.

Candidates (every one a sum of transfer functions the daemon steps as terms):

- ``arx``: one denominator shared by every input, least squares on the
  equation error with a level per record (the textbook baseline; biased by
  displacement noise, robust to correlated inputs);
- ``shared-oe``: the same structure refined by output error
  (`models.identify.output_error`);
- ``ridge``: the shared-oe denominator kept, the numerators re-estimated by
  ridge regression on the filtered inputs u_t/B (the regularised answer to
  nearly collinear sensors: large opposite gains cost), λ chosen by the same
  cross-validation;
- ``per-term-oe``: one denominator per input (the papers' structure).

Orders (denominator na, numerator length nb shared by every input) are
chosen first, by the cross-validated Steiglitz–McBride estimate
(`choose_orders`) for the structures refined from it, and by the
cross-validated ARX least squares itself for the ``arx`` candidate
(`arx_orders`); then each structure is trained on
every fold and scored on the held-out block (`models.identify.validate`),
and re-estimated on every row. The chosen structure is the simplest (fewest
parameters, then the better validated) among those within `margin` points
of the best validated one; the ARX baseline is always among the candidates, so a
structure that validates below it is never chosen silently.

Validation is forward by default (`models.identify.validate.forward_masks`:
each held-out block predicted by a model trained on the rows before it),
as the model will be used. Every final estimate is checked
(`models.identify.checks.implausible`: cancelling gains, a DC gain out of
proportion, a pole slower than the records); a rejected one stays in the
table with its reason and is never chosen. When the orders asked for give
nothing plausible, first order and then a static model (a gain per input,
a level per record) are tried, and the failures are kept as notes.

The search's parts live beside this module: the data and folds
(`models.identify.fold_data`), the estimators trained on a fold
(`models.identify.estimators`), how an estimate is scored
(`models.identify.fold_scores`) and the order search (`models.identify.orders`).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from models.identify.estimators import (
    OE_TOL,
    RIDGE_GRID,
    SM_ITERATIONS,
    _arx_fit,
    _fold_models,
    _oe,
    _ridge,
    _static_fit,
    arx_fit,
)
from models.identify.fold_data import (
    DEFAULT_FOLDS,
    DEFAULT_VALIDATION,
    _Data,
    make_data,
    rows_key,
)
from models.identify.fold_scores import _final_fit, _heldout, _Replay, _score, _simulate
from models.identify.orders import (
    INITIAL_MARGIN_PCT,
    arx_orders,
    choose_orders,
    order_search_result,
    order_search_score,
)
from models.identify.output_error import OeModel
from models.identify.segments import Segments

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

# the search's parts, named here as well for the callers that import them from
# this module
__all__ = ["DEFAULT_FOLDS", "DEFAULT_VALIDATION", "INITIAL_MARGIN_PCT", "OE_TOL", "RIDGE_GRID",
           "SM_ITERATIONS", "STRUCTURES", "Candidate", "Selection", "_Data", "_arx_fit",
           "_fold_models", "_heldout", "_ridge", "_score", "_simulate", "_static_fit", "arx_fit",
           "arx_orders", "choose_orders", "make_data", "order_search_result",
           "order_search_score", "select_structure"]

STRUCTURES: tuple[str, ...] = ("arx", "shared-oe", "ridge", "per-term-oe")


@dataclass(frozen=True)
class Candidate:
    structure: str
    model: OeModel
    validation_fit_pct: float
    fold_fits: tuple[float, ...]
    #: fit % of the final estimate simulated over every record (initial
    #: conditions estimated)
    fit_pct: float = math.nan
    detail: str = ""
    #: why the final estimate is implausible (`models.identify.checks`): never chosen
    rejected: str = ""
    #: RMS of the residue on rows it was not calibrated on (`_heldout`), µm
    heldout_rms: float = math.nan
    #: RMS of the displacement itself on those rows (no compensation), µm
    displacement_rms: float = math.nan
    #: the residue on those rows, one array per contiguous held-out block (each
    #: predicted by a model trained without it): the error the model makes on
    #: what it was not calibrated on, from which `compd fit --adaptation`
    #: learns how fast that error moves
    heldout_residuals: tuple[FloatArray, ...] = field(default=(), compare=False, repr=False)
    #: (`rows_key` of a fold's training rows, the estimate the selection's chain
    #: made on them) per fold: a verdict that asks for the same chain on the
    #: same rows takes it (`compd.offline.fit_judge.refit`) instead of fitting again
    fold_models: tuple[tuple[bytes, OeModel | None], ...] = field(default=(), compare=False,
                                                                   repr=False)

    @property
    def n_params(self) -> int:
        return self.model.n_params


@dataclass(frozen=True)
class Selection:
    chosen: Candidate
    candidates: tuple[Candidate, ...]
    orders: tuple[int, int]
    notes: tuple[str, ...] = field(default_factory=tuple)
    #: initial conditions estimated with the model (the records start warm)
    initial: bool = False
    #: the orders asked for gave nothing plausible: a first-order or static model
    fallback: bool = False

    @property
    def baseline(self) -> Candidate | None:
        """The ARX least-squares candidate (None: unstable at these orders)."""
        return next((c for c in self.candidates if c.structure in ("arx", "static")), None)


def select_structure(y: FloatArray, inputs: Sequence[FloatArray], *,
                     na_range: tuple[int, int], nb_range: tuple[int, int],
                     segments: Segments | None = None, radius: float = 1.0,
                     folds: int = DEFAULT_FOLDS, validation: str = DEFAULT_VALIDATION,
                     structures: Sequence[str] = STRUCTURES, margin_pct: float = 0.5,
                     max_iter: int = 40,
                     holdout: tuple[FloatArray, Sequence[FloatArray], Segments] | None = None,
                     names: Sequence[str] | None = None, usable: BoolArray | None = None,
                     veto: Callable[[OeModel], str | None] | None = None) -> Selection:
    """Cross-validate every structure at the ARX-chosen orders; re-estimate on
    every row; choose (module docstring). With `holdout` records the
    candidates train on every row and are scored on those records instead
    (initial conditions from each one's first half, as `compd replay`).
    `usable`: the only rows any loss counts (`make_data`), every record still
    simulated from its start. `veto(model)`: why a final estimate must not be
    chosen besides the diagnostics here (None: it may), kept in the table as a
    rejection."""
    unknown = sorted(set(structures) - set(STRUCTURES))
    if unknown:
        raise ValueError(f"unknown structure(s) {unknown}; known: {list(STRUCTURES)}")
    seg = segments if segments is not None else Segments.single(np.asarray(y).size)
    d = make_data(y, inputs, seg, radius, folds, validation, usable, veto)
    if holdout is not None:
        d.holdout = (np.asarray(holdout[0], dtype=np.float64),
                     [np.asarray(u, dtype=np.float64) for u in holdout[1]], holdout[2])
        d.splits = [(d.every, np.zeros(d.y.size, dtype=bool))]
        d.blocked = None
    labels = d.labels(names)
    failed: list[str] = []
    # the orders asked for, then first order, then static: every channel gets
    # the best model its diagnostics accept, and the ones that failed are said
    for stage, (na_r, nb_r) in (("orders", (na_range, nb_range)), ("first order", ((1, 1), (1, 1))),
                                ("static", ((0, 0), (1, 1)))):
        if stage == "first order" and na_range == (1, 1) and nb_range == (1, 1):
            continue
        try:
            cands, orders, initial = _candidates_at(d, na_r, nb_r, structures, max_iter,
                                                    labels)
        except ValueError as exc:
            failed.append(f"{_stage_name(stage, na_range, nb_range)}: {exc}")
            continue
        plausible = [c for c in cands if not c.rejected and math.isfinite(c.validation_fit_pct)]
        if not plausible:
            why = "; ".join(f"{c.structure} {c.rejected or 'not validated'}" for c in cands)
            failed.append(f"{_stage_name(stage, na_range, nb_range)}: {why}")
            continue
        sel = _choose(cands, orders, margin_pct, initial)
        # a rejected candidate's reason is its own (`Candidate.rejected`, printed in the
        # table of candidates), not a note as well
        notes = [f"failed: {f}" for f in failed] + list(sel.notes)
        return Selection(chosen=sel.chosen, candidates=sel.candidates, orders=sel.orders,
                         notes=tuple(notes), initial=sel.initial, fallback=stage != "orders")
    raise ValueError("nothing could be fitted: " + "; ".join(failed))


def _stage_name(stage: str, na_range: tuple[int, int], nb_range: tuple[int, int]) -> str:
    if stage == "orders":
        return (f"denominator orders {na_range[0]}-{na_range[1]}, numerator lengths "
                f"{nb_range[0]}-{nb_range[1]}")
    return stage


def _candidates_at(d: _Data, na_range: tuple[int, int], nb_range: tuple[int, int],
                   structures: Sequence[str], max_iter: int, labels: Sequence[str]
                   ) -> tuple[list[Candidate], tuple[int, int], bool]:
    """Every structure validated at the orders chosen in the ranges, each
    final estimate checked (`implausible`); na = 0: the static model."""
    every = d.every
    if na_range == (0, 0):
        d.initial = True
        val, per = _score(d, functools.partial(_static_fit, d))
        m = _static_fit(d, every)
        if m is None:
            raise ValueError("fewer rows than parameters")
        why = d.refused(m, labels)
        static = [_static_fit(d, t) for t, _ in d.splits]
        held = _heldout(d, static)
        return ([Candidate("static", m, val, tuple(per), _final_fit(d, m), rejected=why,
                           heldout_rms=held.rms, displacement_rms=held.displacement_rms,
                           heldout_residuals=held.residuals,
                           fold_models=_keyed(d, static))], (0, 1), True)
    na, nb, initial = choose_orders(d, na_range, nb_range)
    arx_at = arx_orders(d, na_range, nb_range)
    # the final estimates first: the folds are fitted only when one may be chosen
    finals = _fold_models(d, na, nb, every, structures, max_iter, arx_at)
    hopeless = _every_final_refused(d, finals, labels, structures)
    if hopeless is not None:
        return hopeless, (na, nb), initial
    per_fold = [_fold_models(d, na, nb, train, structures, max_iter, arx_at, per_term=False)
                for train, _ in d.splits]
    keys = list(per_fold[0])
    scores: dict[str, tuple[float, list[float]]] = {}
    for key in keys:
        scores[key] = _score(d, _Replay([pf[key] for pf in per_fold]))
    ridge_keys = [k for k in keys if k.startswith("ridge:")]
    if ridge_keys:
        best_lam = max(ridge_keys, key=lambda k: scores[k][0])
        scores["ridge"] = scores[best_lam]
        finals["ridge"] = finals[best_lam]
        for pf in per_fold:
            pf["ridge"] = pf[best_lam]
    # the diagnostics in the table's order (a veto may count what it refuses)
    refused = {n: d.refused(m, labels) for n in ("arx", "shared-oe", "ridge", "per-term-oe")
               if (n in structures or n == "arx") and (m := finals.get(n)) is not None}
    names = list(refused)
    if "per-term-oe" in refused and not all(refused.values()):
        # per-term-oe's folds start from shared-oe's: fitted only when a
        # candidate is accepted (else the stage fails whatever they validate)
        for (train, _), pf in zip(d.splits, per_fold, strict=True):
            pf["per-term-oe"] = _oe(d, pf["shared-oe"], train, True, max_iter)
        scores["per-term-oe"] = _score(d, _Replay([pf["per-term-oe"] for pf in per_fold]))
    cands: list[Candidate] = []
    for name in names:
        m = finals.get(name)
        val, per = scores.get(name, (-math.inf, []))
        if m is None:
            continue
        detail = f"λ = {best_lam.partition(':')[2]}" if name == "ridge" else ""
        why = refused[name]
        held = _heldout(d, [pf.get(name) for pf in per_fold])
        folds = _keyed(d, [pf[name] for pf in per_fold]) if all(
            name in pf for pf in per_fold) else ()
        cands.append(Candidate(name, m, val, tuple(per), _final_fit(d, m), detail, why,
                               held.rms, held.displacement_rms, held.residuals, folds))
    if not cands:
        raise ValueError("every structure gave an unstable model")
    return cands, (na, nb), initial


def _every_final_refused(d: _Data, finals: dict[str, OeModel | None], labels: Sequence[str],
                         structures: Sequence[str]) -> list[Candidate] | None:
    """The stage's candidates, each refused, when every final estimate is refused
    whatever the folds validate (ridge: at every λ of the grid, for the same
    reason, so that the λ the folds would choose changes nothing); else None
    (the folds decide). Their refusals are then asked in the table's order, as
    `_candidates_at` asks them, and the stage fails on them without a fold fitted
    (a day at 1 s: the fold fits, scores and residues of orders 2-4 that every
    model fails)."""
    ridge = [m for k, m in finals.items() if k.startswith("ridge:")]
    if ridge and (any(m is None for m in ridge) or len(
            {d.refused(m, labels, quietly=True) for m in ridge if m is not None}) != 1):
        return None
    finals = {**finals, "ridge": ridge[0]} if ridge else finals
    names = [n for n in ("arx", "shared-oe", "ridge", "per-term-oe")
             if (n in structures or n == "arx") and finals.get(n) is not None]
    if not all(d.refused(m, labels, quietly=True) for n in names
               if (m := finals[n]) is not None):
        return None
    out = []
    for n in names:
        m = finals[n]
        assert m is not None
        detail = "λ = (every one refused)" if n == "ridge" else ""
        out.append(Candidate(n, m, -math.inf, (), math.nan, detail, d.refused(m, labels)))
    if not out:
        raise ValueError("every structure gave an unstable model")
    return out


def _keyed(d: _Data, models: Sequence[OeModel | None]
           ) -> tuple[tuple[bytes, OeModel | None], ...]:
    """Each fold's estimate with the key of its training rows (`Candidate.fold_models`)."""
    return tuple((rows_key(t), m) for (t, _), m in zip(d.splits, models, strict=True))


def _choose(cands: list[Candidate], orders: tuple[int, int], margin_pct: float,
            initial: bool) -> Selection:
    finite = [c for c in cands if math.isfinite(c.validation_fit_pct) and not c.rejected]
    notes: list[str] = []
    if not finite:
        raise ValueError("no structure could be validated (every fold unstable)")
    best = max(c.validation_fit_pct for c in finite)
    near = [c for c in finite if c.validation_fit_pct >= best - margin_pct]
    # fewest parameters; among as many, the better validated (the ARX
    # baseline has as many as shared-oe, and its noise bias shows off the
    # folds: the bench machine's spectrum run, 86.3 % against 90.6 %)
    chosen = min(near, key=lambda c: (c.n_params, -c.validation_fit_pct))
    if chosen.validation_fit_pct < best:
        notes.append(f"{chosen.structure} chosen: within {margin_pct:g} points of the best "
                     f"validated ({best:.2f} %) and simpler")
    if best < 0.0:
        notes.append(f"every structure validates below 0 % (best {best:.2f} %): the "
                     "inputs do not explain the held-out displacement")
    ordered = sorted(cands, key=lambda c: -c.validation_fit_pct
                     if math.isfinite(c.validation_fit_pct) else math.inf)
    if chosen.structure == "arx":  # validated at its own orders (`arx_orders`)
        orders = (len(chosen.model.dens[0]) - 1, len(chosen.model.nums[0]))
    return Selection(chosen=chosen, candidates=tuple(ordered), orders=orders, notes=tuple(notes),
                     initial=initial)
