"""Transfer-function terms from a record: ARX start, output-error structure
search, output-error fit on the whole record.

1. ARX (`models.identify.arx.select_arx`) over every order combination:
   cheap, and a good starting point, but biased by displacement noise: its
   validation scores are often flat across structures.
2. Output-error structure search, greedy from the ARX choice: fit OE on the
   first 70 % of the record, score the simulation on the last 30 %, then try
   one more numerator or denominator coefficient per term, warm-started from
   the current estimate with the new coefficient at 0 (so it can only fit the
   training part better); a step is taken only when the validation fit gains
   more than `tolerance_pct` points: a higher order must earn its place.
3. OE on the whole record from the chosen estimate.

Several records (`segments`) are fitted jointly as separate experiments:
each restarts from rest; the structure search trains on the first 70 % of
every record and scores the last 30 % of each, or, given a held-out
validation set (`holdout`), trains on every calibration record whole and
scores the simulation of the held-out records. Every pole is kept within
|p| < `radius` (a longest time constant, `segments.pole_radius`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from models.identify.arx import ArxEstimate, fit_pct, refit, select_arx, simulate_common
from models.identify.output_error import OeEstimate, refine_oe
from models.identify.reflection import step_down, step_up
from models.identify.segments import Segments

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class TfFit:
    arx: ArxEstimate
    #: ARX simulation fit % on the whole record
    arx_fit_pct: float
    oe: OeEstimate
    #: OE validation fit % of the chosen structure (trained on the first part)
    oe_validation_fit_pct: float
    #: per term (numerator length, denominator order)
    orders: tuple[tuple[int, int], ...]


@dataclass(frozen=True)
class Holdout:
    """Records kept out of the fit, used only to choose the structure."""

    y: FloatArray
    inputs: tuple[FloatArray, ...]
    segments: Segments


def _simulate(nums: Sequence[Sequence[float]], dens: Sequence[Sequence[float]],
              inputs: Sequence[FloatArray], segments: Segments | None = None) -> FloatArray:
    seg = segments if segments is not None else Segments.single(inputs[0].size)
    total = np.zeros_like(inputs[0])
    for a, b, u in zip(nums, dens, inputs, strict=True):
        total += seg.filter(np.asarray(a), np.asarray(b), u)
    return total


def _grow_den(den: Sequence[float]) -> tuple[float, ...]:
    """One more denominator coefficient, the same poles plus one at 0."""
    kappa = np.append(step_down(den), 0.0)
    return tuple(float(v) for v in step_up(kappa))


def _greedy(score: Callable[[Sequence[Sequence[float]], Sequence[Sequence[float]]],
                            tuple[OeEstimate, float]],
            nums0: Sequence[Sequence[float]], dens0: Sequence[Sequence[float]], n_terms: int,
            na_range: tuple[int, int], nb_range: tuple[int, int], tolerance_pct: float,
            max_rounds: int) -> tuple[OeEstimate, float]:
    best, best_val = score(nums0, dens0)
    for _ in range(max_rounds):
        trials: list[tuple[list[tuple[float, ...]], list[tuple[float, ...]]]] = []
        for t in range(n_terms):
            if len(best.nums[t]) < nb_range[1]:
                nums = list(best.nums)
                nums[t] = (*nums[t], 0.0)
                trials.append((nums, list(best.dens)))
            if len(best.dens[t]) - 1 < na_range[1]:
                dens = list(best.dens)
                dens[t] = _grow_den(dens[t])
                trials.append((list(best.nums), dens))
        scored = [score(n, d) for n, d in trials]
        if not scored:
            break
        cand, cand_val = max(scored, key=lambda s: s[1] if math.isfinite(s[1]) else -math.inf)
        if not cand_val > best_val + tolerance_pct:
            break
        best, best_val = cand, cand_val
    return best, best_val


def fit_tf_terms(y: FloatArray, inputs: Sequence[FloatArray], na_range: tuple[int, int],
                 nb_range: tuple[int, int], *, validation: float = 0.3,
                 tolerance_pct: float = 0.1, max_rounds: int = 6,
                 segments: Segments | None = None, radius: float = 1.0,
                 holdout: Holdout | None = None) -> TfFit:
    y = np.asarray(y, dtype=np.float64)
    us = [np.asarray(u, dtype=np.float64) for u in inputs]
    seg = segments if segments is not None else Segments.single(y.size)
    arx, _ = select_arx(y, us, na_range, nb_range, validation=validation,
                        tolerance_pct=tolerance_pct, segments=seg, radius=radius)
    arx_fit = fit_pct(y, simulate_common(arx.den, arx.nums, us, seg))
    if holdout is None:
        seg_tr = seg.heads(validation)
        y_tr, us_tr = seg.take_heads(y, validation), [seg.take_heads(u, validation) for u in us]
        _, val_mask = seg.head_mask(0, validation)
        y_val, us_val, seg_val = y, us, seg
    else:
        seg_tr, y_tr, us_tr = seg, y, us
        y_val, us_val, seg_val = holdout.y, list(holdout.inputs), holdout.segments
        val_mask = np.ones(y_val.size, dtype=bool)

    def score(nums: Sequence[Sequence[float]],
              dens: Sequence[Sequence[float]]) -> tuple[OeEstimate, float]:
        est = refine_oe(y_tr, us_tr, nums, dens, max_iter=25, tol=1e-8, segments=seg_tr,
                        radius=radius)
        sim = _simulate(est.nums, est.dens, us_val, seg_val)
        val = fit_pct(y_val[val_mask], sim[val_mask])
        return est, val

    starts = [(arx.nums, [arx.den] * len(us))]
    # a second start at the papers' smallest dynamic structure, a0 + a1·q⁻¹ over
    # 1 + b1·q⁻¹ per term: a biased ARX choice can be a poor OE basin
    nb_small = min(nb_range[0] + 1, nb_range[1])
    if (arx.na, arx.nbs) != (na_range[0], (nb_small,) * len(us)):
        small = refit(y, us, na_range[0], [nb_small] * len(us), segments=seg)
        starts.append((small.nums, [small.den] * len(us)))
    results = [_greedy(score, nums, dens, len(us), na_range, nb_range, tolerance_pct,
                       max_rounds) for nums, dens in starts]
    top = max(v for _, v in results)
    best, best_val = min((r for r in results if r[1] >= top - tolerance_pct),
                         key=lambda r: (sum(len(a) + len(b) for a, b in
                                            zip(r[0].nums, r[0].dens, strict=True)), -r[1]))
    final = refine_oe(y, us, best.nums, best.dens, max_iter=60, tol=1e-10, segments=seg,
                      radius=radius)
    orders = tuple((len(a), len(b) - 1) for a, b in zip(final.nums, final.dens, strict=True))
    return TfFit(arx=arx, arx_fit_pct=arx_fit, oe=final, oe_validation_fit_pct=best_val,
                 orders=orders)
