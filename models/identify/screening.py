"""A second screen for the subset search (`models.identify.subsets`): a
small fixed model, validated forward.

A subset is judged by the equation-error ARX at `SCREEN_ORDERS` (a
denominator of order 2, numerator length 3 per input: the textbook
two-sensor thermal model), one denominator shared, run from each record's
start, each held-out block predicted by the estimate on the rows before it
(`models.identify.validate.forward_masks`). Initial conditions are
estimated only when they validate better on blocked folds, as
`models.identify.structures.choose_orders` decides it.

Why beside the flexible screen (Steiglitz–McBride at the best of the
orders): the first forward fold trains on a fifth of the calibration (one
speed for 4 h on the real record); a flexible estimate fits that regime and
may fail the next whatever its inputs, so its figure partly measures the
estimator's variance. A fixed small model ranks inputs differently (on the
real record's ch3 calibrated on 20.1 h, the flexible screen's favourite
t4 + t12 was never compared with t4 + t8 + t11, which the fixed screen
ranks first and which then leaves 3.96 µm MAE on the unseen 5000 rpm step
instead of 6.85). Neither screen is trusted alone: `compd fit` validates
the structures on the winner of each and keeps the better validated.

Worked number: a 5-block record; fold 1 trains ARX(2, 3) on block 1 and
scores block 2, …, fold 4 trains on blocks 1-4 and scores block 5.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence

import numpy as np
import numpy.typing as npt

from models.identify.estimators import arx_fit
from models.identify.fold_data import DEFAULT_FOLDS, DEFAULT_VALIDATION, _Data, make_data
from models.identify.fold_scores import _score
from models.identify.orders import INITIAL_MARGIN_PCT
from models.identify.output_error import OeModel
from models.identify.segments import Segments

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

#: (denominator order, numerator length) of the screening ARX, each clamped
#: into the orders the caller allows
SCREEN_ORDERS = (2, 3)


def _clamp(v: int, lo_hi: tuple[int, int]) -> int:
    return min(max(v, lo_hi[0]), lo_hi[1])


def screen_subset(y: FloatArray, inputs: Sequence[FloatArray], *,
                  na_range: tuple[int, int], nb_range: tuple[int, int],
                  segments: Segments | None = None, radius: float = 1.0,
                  folds: int = DEFAULT_FOLDS, validation: str = DEFAULT_VALIDATION,
                  names: Sequence[str] | None = None, usable: BoolArray | None = None
                  ) -> tuple[float, str | None]:
    """(validated fit % of the screening ARX, why its estimate on every row
    is implausible (`models.identify.checks.implausible`) or None); -inf
    when a fold gives no stable model."""
    seg = segments if segments is not None else Segments.single(np.asarray(y).size)
    d = make_data(y, inputs, seg, radius, folds, validation, usable)
    na, nb = _clamp(SCREEN_ORDERS[0], na_range), _clamp(SCREEN_ORDERS[1], nb_range)
    fit = functools.partial(arx_fit, d, na, nb)
    d.initial = _initial_helps(d, fit)
    val, _ = _score(d, fit)
    if not math.isfinite(val):
        return val, "unstable on a fold"
    m = fit(d.every)
    if m is None:
        return val, "unstable on every row"
    return val, d.refused(m, d.labels(names)) or None


def _initial_helps(d: _Data, fit: Callable[[BoolArray], OeModel | None]) -> bool:
    """Estimated initial conditions validate better than a rest start by
    `INITIAL_MARGIN_PCT`, on blocked folds (the question is about each
    record's start, not about what follows it)."""
    splits = d.splits
    if d.blocked is not None:
        d.splits = d.blocked
    d.initial = True
    v_init, _ = _score(d, fit)
    d.initial = False
    v_rest, _ = _score(d, fit)
    d.splits = splits
    return bool(v_init > v_rest + INITIAL_MARGIN_PCT)
