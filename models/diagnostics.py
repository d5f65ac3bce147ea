"""Diagnostics a calibration engineer reads (warnings, never refusals).

- Cancelling terms: two terms with large gains of opposite sign on strongly
  correlated inputs predict mostly the small difference of two large
  numbers; a sensor fault or a slightly different heat path on the next day
  becomes a large error. Flagged when |r| >= `CORRELATED_R` and the gains'
  signs differ and each term alone would move the output by more than the
  measured span; the condition number of the (scaled) input matrix says how
  ill-posed the split between them is.
- A nearly flat verification window: a fit % compares the residue with the
  measured spread; a window that hardly moves gives a meaningless (often
  very negative, or flattering) figure. Flagged when its range is below
  `FLAT_RANGE_UM` or below three times the residue's standard deviation.

Worked number: inputs correlated at r = 0.99 with gains -15.5 and +23.6 µm/K
over a 3 K span (46 and 71 µm each) on a 20 µm record are flagged.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

#: correlation from which two inputs count as nearly collinear
CORRELATED_R = 0.95
#: condition number of the scaled input matrix worth a warning
CONDITION_WARN = 100.0
#: a verification window spanning less than this (µm) is nearly flat
FLAT_RANGE_UM = 2.0


#: inputs longer than this are reduced block by block to their Gram matrix (the
#: centred columns of a month at 1 s, stacked and copied for the SVD, were 330 MB)
GRAM_ROWS = 1 << 17


def input_condition(inputs: Sequence[FloatArray]) -> float:
    """Condition number of the centred, unit-norm input columns (past
    `GRAM_ROWS` rows from their Gram matrix, accumulated block by block: the
    same figure while it is far below 1e7)."""
    if len(inputs) < 2:
        return 1.0
    if inputs[0].size > GRAM_ROWS:
        return _condition_by_blocks(inputs)
    x = np.stack([u - u.mean() for u in inputs], axis=1)
    norms = np.linalg.norm(x, axis=0)
    if np.any(norms == 0.0):
        return float("inf")
    return float(np.linalg.cond(x / norms))


def _condition_by_blocks(inputs: Sequence[FloatArray]) -> float:
    """`input_condition` through the centred columns' Gram matrix, summed over
    blocks of `GRAM_ROWS` rows: cond = sqrt(λmax / λmin) of the correlation matrix."""
    means = [u.mean() for u in inputs]
    n = inputs[0].size
    gram = np.zeros((len(inputs), len(inputs)))
    for lo in range(0, n, GRAM_ROWS):
        x = np.stack([u[lo:lo + GRAM_ROWS] - m for u, m in zip(inputs, means, strict=True)],
                     axis=1)
        gram += x.T @ x
    norms = np.sqrt(np.diag(gram))
    if np.any(norms == 0.0):
        return float("inf")
    eig = np.linalg.eigvalsh(gram / norms[:, None] / norms[None, :])
    return float(np.sqrt(eig[-1] / eig[0])) if eig[0] > 0.0 else float("inf")


def correlation(a: FloatArray, b: FloatArray) -> float:
    """Pearson's r of two inputs: `numpy.corrcoef`'s up to `GRAM_ROWS` rows; past
    them from centred sums taken block by block (corrcoef stacks and centres
    both, four copies of a month's column)."""
    if a.size <= GRAM_ROWS:
        return float(np.corrcoef(a, b)[0, 1])
    ma, mb = a.mean(), b.mean()
    sab = saa = sbb = 0.0
    for lo in range(0, a.size, GRAM_ROWS):
        da, db = a[lo:lo + GRAM_ROWS] - ma, b[lo:lo + GRAM_ROWS] - mb
        sab += float(da @ db)
        saa += float(da @ da)
        sbb += float(db @ db)
    return sab / math.sqrt(saa * sbb) if saa > 0.0 and sbb > 0.0 else math.nan


@dataclass(frozen=True)
class CancellingPair:
    """Inputs `i` and `j` correlated at `r` whose terms cancel each other."""

    i: int
    j: int
    r: float


def cancelling_pairs(inputs: Sequence[FloatArray], gains: Sequence[float],
                     output_span: float, min_r: float = CORRELATED_R) -> list[CancellingPair]:
    """Every pair of inputs correlated at |r| >= `min_r` whose terms' DC gains
    push opposite ways and each alone move the output by more than
    `output_span` over its input's range (the model predicts the small
    difference of two large numbers); a constant input correlates with none.
    The one test of cancelling terms: `cancelling_terms` warns of them, fit's
    selection (`models.identify.checks.implausible`) rejects them."""
    out: list[CancellingPair] = []
    for i in range(len(inputs)):
        for j in range(i + 1, len(inputs)):
            a, b = inputs[i], inputs[j]
            if np.std(a) == 0.0 or np.std(b) == 0.0:
                continue
            r = correlation(a, b)
            big = (abs(gains[i]) * float(np.ptp(a)) > output_span
                   and abs(gains[j]) * float(np.ptp(b)) > output_span)
            if abs(r) >= min_r and gains[i] * gains[j] * r < 0.0 and big:
                out.append(CancellingPair(i, j, r))
    return out


def cancelling_terms(names: Sequence[str], inputs: Sequence[FloatArray],
                     gains: Sequence[float], output_span: float) -> list[str]:
    """One warning per pair of terms that cancel (module docstring)."""
    cond = input_condition(inputs)
    out = [f"terms {names[p.i]!r} and {names[p.j]!r} cancel each other: DC gains "
           f"{gains[p.i]:+.4g} and {gains[p.j]:+.4g} on inputs correlated at "
           f"r = {p.r:.3f} (condition number {cond:.3g}); the model predicts "
           "the small difference of two large terms: keep one of them, or "
           "use --structure ridge or --candidates"
           for p in cancelling_pairs(inputs, gains, output_span)]
    if not out and cond > CONDITION_WARN:
        out.append(f"the inputs are nearly collinear (condition number {cond:.3g}): their "
                   "split between terms is poorly determined")
    return out


def flat_window(measured: FloatArray, residue: FloatArray) -> str | None:
    """A warning when the scored window is nearly flat, else None."""
    span = float(np.ptp(measured))
    noise = float(np.std(residue))
    if span < FLAT_RANGE_UM or span < 3.0 * noise:
        return (f"the scored window spans only {span:.3g} µm (residue σ {noise:.3g} µm): a fit % "
                "of a nearly flat record means little; judge the residue in µm and the range "
                "reduction")
    return None
