"""The orders of a structure search: the cross-validated Steiglitz–McBride
estimate's (`choose_orders`, which also decides whether initial conditions
are estimated), the ARX least squares' own (`arx_orders`), and the order
search alone as a score (`order_search_result`).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence

import numpy as np
import numpy.typing as npt

from models.identify.estimators import _sm, arx_fit
from models.identify.fold_data import DEFAULT_FOLDS, DEFAULT_VALIDATION, _Data, make_data
from models.identify.fold_scores import _score
from models.identify.output_error import OeModel
from models.identify.segments import Segments

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

#: estimated initial conditions must validate this much better than a rest start
INITIAL_MARGIN_PCT = 1.0


def _scan_orders(d: _Data, fit: Callable[[_Data, int, int, BoolArray], OeModel | None],
                 na_range: tuple[int, int], nb_range: tuple[int, int]
                 ) -> list[tuple[float, int, int]]:
    """(validated fit %, na, nb) of `fit` at every order of the ranges, in
    grid order (na outer)."""
    return [(_score(d, functools.partial(fit, d, na, nb))[0], na, nb)
            for na in range(na_range[0], na_range[1] + 1)
            for nb in range(nb_range[0], nb_range[1] + 1)]


def _simplest(scored: Sequence[tuple[float, int, int]]) -> tuple[float, int, int]:
    """Of the orders validated within 0.1 point of the best, those with the
    fewest coefficients (na + nb), the better validated among as many."""
    top = max(v for v, _, _ in scored)
    return min((s for s in scored if s[0] >= top - 0.1), key=lambda s: (s[1] + s[2], -s[0]))


def choose_orders(d: _Data, na_range: tuple[int, int], nb_range: tuple[int, int]
                  ) -> tuple[int, int, bool]:
    """(na, nb, initial) of the best cross-validated Steiglitz–McBride
    estimate (`arx_fit`), smaller orders on
    ties within 0.1 point. The initial conditions are estimated only when
    that validates better by more than `INITIAL_MARGIN_PCT`: on a record that
    starts cold, free levels let the slow modes be mis-identified (the 48 h
    split's first half: 73.9 % run continuously instead of 85.1 %)."""
    d.initial = False
    best = {False: _simplest(_scan_orders(d, _sm, na_range, nb_range))}
    d.initial = True  # at the orders found, then over the grid if it helps
    na0, nb0 = best[False][1:]
    v_init, _ = _score(d, functools.partial(_sm, d, na0, nb0))
    best[True] = (v_init, na0, nb0)
    if d.blocked is not None:
        # whether the records start warm is a question about their starts, not
        # about what follows: judged on blocked folds, where every fold trains
        # on a record's beginning and its end (forward folds trained on one
        # block favoured free levels on the cold-started 48 h split: 75.7 %
        # run continuously instead of 85 %)
        forward, d.splits = d.splits, d.blocked
        v_init_b, _ = _score(d, functools.partial(_sm, d, na0, nb0))
        d.initial = False
        v_rest_b, _ = _score(d, functools.partial(_sm, d, na0, nb0))
        d.splits = forward
        d.initial = v_init_b > v_rest_b + INITIAL_MARGIN_PCT
    else:
        d.initial = v_init > best[False][0] + INITIAL_MARGIN_PCT
    if d.initial:
        best[True] = _simplest(_scan_orders(d, _sm, na_range, nb_range))
    v, na, nb = best[d.initial]
    d.best_order_fit = v
    if not math.isfinite(v):
        bound = (f" or had a pole beyond |p| < {d.radius:.9f} (the slowest allowed time "
                 "constant)" if d.radius < 1.0 else "")
        raise ValueError(f"every ARX order gave an unstable model{bound}: the record does not "
                         "determine a model (too short, or no input variation)")
    return na, nb, d.initial


def arx_orders(d: _Data, na_range: tuple[int, int], nb_range: tuple[int, int]
               ) -> tuple[int, int] | None:
    """(na, nb) of the best validated ARX least squares itself (smaller orders
    on ties within 0.1 point), at the initial conditions already decided;
    None when no order gives a stable one on every fold.
    The ARX candidate is validated at its own orders, not at those of the
    Steiglitz–McBride estimate (`choose_orders`) the output-error structures
    start from: on the real record's ch3 (t4, t8, t11, calibrated on 20.1 h)
    those were first order, where ARX validated at 69.2 % and then left
    5.51 µm MAE on the unseen 5000 rpm step; at its own orders (2, 2) it
    validates at 70.8 % and leaves 3.83 µm."""
    scored = _scan_orders(d, arx_fit, na_range, nb_range)
    if not math.isfinite(max(v for v, _, _ in scored)):
        return None
    _, na, nb = _simplest(scored)
    return na, nb


def order_search_result(y: FloatArray, inputs: Sequence[FloatArray], *,
                        na_range: tuple[int, int], nb_range: tuple[int, int],
                        segments: Segments | None = None, radius: float = 1.0,
                        folds: int = DEFAULT_FOLDS, validation: str = DEFAULT_VALIDATION,
                        names: Sequence[str] | None = None, usable: BoolArray | None = None
                        ) -> tuple[float, str | None]:
    """(the validated fit % of the best Steiglitz–McBride estimate over the
    orders (`choose_orders`), why the estimate on every row is implausible
    (`models.identify.checks.implausible`) or None). -inf when no order gives
    a stable model."""
    seg = segments if segments is not None else Segments.single(np.asarray(y).size)
    d = make_data(y, inputs, seg, radius, folds, validation, usable)
    try:
        na, nb, _ = choose_orders(d, na_range, nb_range)
    except ValueError as exc:
        return -math.inf, str(exc)
    m = _sm(d, na, nb, d.every)
    if m is None:
        return d.best_order_fit, "unstable on every row"
    labels = d.labels(names)
    return d.best_order_fit, d.refused(m, labels) or None


def order_search_score(y: FloatArray, inputs: Sequence[FloatArray], *,
                       na_range: tuple[int, int], nb_range: tuple[int, int],
                       segments: Segments | None = None, radius: float = 1.0,
                       folds: int = DEFAULT_FOLDS, validation: str = DEFAULT_VALIDATION
                       ) -> float:
    """The validated fit % of `order_search_result` (plausible or not)."""
    return order_search_result(y, inputs, na_range=na_range, nb_range=nb_range,
                               segments=segments, radius=radius, folds=folds,
                               validation=validation)[0]
