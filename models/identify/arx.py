"""ARX identification by linear least squares, with order selection.

Multi-input ARX with one denominator shared by every term (docs/models.md §2
naming: numerator ``a``, denominator ``b``, b0 = 1)::

    y(k) = -Σ_{i=1..na} b_i·y(k-i) + Σ_terms Σ_{j=0..nb_t-1} a_tj·u_t(k-j)

Inputs are relative (ΔT from the first sample). The regressor matrix is built
ONCE at the largest orders and factorised once (QR of the column-scaled
training rows); every order combination is then a small least-squares problem
on a column subset of R (k × k with k ≤ na_max + Σ nb_max), so trying 4 × 4³
combinations costs little more than one fit.

Orders are chosen by the *simulation* fit % on a held-out validation tail
(one-step ARX predictions of a slow thermal process are always ~100 %): the
model estimated on the first 70 % is simulated over the whole record and
scored on the last 30 %. A larger structure must beat the best fit by more
than `tolerance_pct` percentage points to be chosen over a smaller one.

Several records (`segments`, see `models.identify.segments`) are separate
experiments: their regressors are zero before each record's start, the
simulations restart from rest per record, and each record's own first 70 %
trains while its last 30 % validates.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from models.identify.segments import Segments

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class ArxEstimate:
    """One ARX model: shared denominator `den` (den[0] = 1) and one numerator
    per input; `validation_fit_pct` the held-out simulation fit %."""

    den: tuple[float, ...]
    nums: tuple[tuple[float, ...], ...]
    validation_fit_pct: float

    @property
    def na(self) -> int:
        return len(self.den) - 1

    @property
    def nbs(self) -> tuple[int, ...]:
        return tuple(len(a) for a in self.nums)

    @property
    def n_params(self) -> int:
        return self.na + sum(self.nbs)


def lagged(x: FloatArray, lags: int, start: int = 0) -> FloatArray:
    """Columns x(k-start), …, x(k-start-lags+1), zero before the record."""
    n = x.size
    out = np.zeros((n, lags))
    for j in range(lags):
        d = start + j
        out[d:, j] = x[: n - d]
    return out


def regressors(y: FloatArray, inputs: Sequence[FloatArray], na_max: int,
               nb_max: int, segments: Segments | None = None) -> FloatArray:
    """[-y(k-1) … -y(k-na_max) | u_1(k) … u_1(k-nb_max+1) | u_2 … ] (n rows)."""
    if segments is None or len(segments.bounds) == 1:
        blocks = [-lagged(y, na_max, start=1)] + [lagged(u, nb_max) for u in inputs]
    else:
        blocks = [-segments.lagged(y, na_max, start=1)] + [segments.lagged(u, nb_max)
                                                           for u in inputs]
    return np.hstack(blocks)


def simulate_common(den: Sequence[float], nums: Sequence[Sequence[float]],
                    inputs: Sequence[FloatArray], segments: Segments | None = None
                    ) -> FloatArray:
    """y = (Σ_t A_t(q) u_t) / B(q) from rest (per segment)."""
    seg = segments if segments is not None else Segments.single(inputs[0].size)
    v = np.zeros_like(inputs[0])
    for a, u in zip(nums, inputs, strict=True):
        v += seg.filter(np.asarray(a), [1.0], u)
    return seg.filter([1.0], np.asarray(den), v)


def fit_pct(measured: FloatArray, simulated: FloatArray) -> float:
    spread = float(np.linalg.norm(measured - measured.mean()))
    if spread == 0.0 or not np.all(np.isfinite(simulated)):
        return -math.inf
    return (1.0 - float(np.linalg.norm(measured - simulated)) / spread) * 100.0


def is_stable(den: Sequence[float], radius: float = 1.0) -> bool:
    """Every pole strictly inside |p| < radius."""
    if len(den) < 2:
        return True
    return bool(np.all(np.abs(np.roots(np.asarray(den))) < radius))


def _columns(na: int, nbs: Sequence[int], na_max: int, nb_max: int) -> list[int]:
    cols = list(range(na))
    for t, nb in enumerate(nbs):
        base = na_max + t * nb_max
        cols += list(range(base, base + nb))
    return cols


def _split(theta: FloatArray, na: int, nbs: Sequence[int]) -> tuple[tuple[float, ...],
                                                                     tuple[tuple[float, ...], ...]]:
    den = (1.0, *(float(v) for v in theta[:na]))
    nums: list[tuple[float, ...]] = []
    i = na
    for nb in nbs:
        nums.append(tuple(float(v) for v in theta[i:i + nb]))
        i += nb
    return den, tuple(nums)


def select_arx(y: FloatArray, inputs: Sequence[FloatArray], na_range: tuple[int, int],
               nb_range: tuple[int, int], *, validation: float = 0.3,
               tolerance_pct: float = 0.1, segments: Segments | None = None,
               radius: float = 1.0) -> tuple[ArxEstimate, list[ArxEstimate]]:
    """Try every (na, nb_1, …, nb_T) in the ranges; return the chosen structure
    re-estimated on the whole record, and every candidate scored on validation
    (a candidate with a pole at or beyond `radius` scores -inf)."""
    y = np.asarray(y, dtype=np.float64)
    us = [np.asarray(u, dtype=np.float64) for u in inputs]
    na_lo, na_hi = na_range
    nb_lo, nb_hi = nb_range
    if not (1 <= na_lo <= na_hi and 1 <= nb_lo <= nb_hi):
        raise ValueError(f"orders must satisfy 1 <= lo <= hi, got {na_range} and {nb_range}")
    seg = segments if segments is not None else Segments.single(y.size)
    phi = regressors(y, us, na_hi, nb_hi, seg)
    lag = max(na_hi, nb_hi - 1)
    train, val = seg.head_mask(lag, validation)
    scale = np.sqrt(np.mean(phi[train] ** 2, axis=0))
    scale[scale == 0.0] = 1.0
    q, r = np.linalg.qr(phi[train] / scale, mode="reduced")
    qty = q.T @ y[train]
    y_val = y[val]
    candidates: list[ArxEstimate] = []
    for na in range(na_lo, na_hi + 1):
        for nbs in itertools.product(range(nb_lo, nb_hi + 1), repeat=len(us)):
            cols = _columns(na, nbs, na_hi, nb_hi)
            theta, *_ = np.linalg.lstsq(r[:, cols], qty, rcond=None)
            theta = theta / scale[cols]
            den, nums = _split(theta, na, nbs)
            score = -math.inf
            if is_stable(den, radius):
                v = phi[:, cols[na:]] @ theta[na:]
                sim = seg.filter([1.0], np.asarray(den), v)
                score = fit_pct(y_val, sim[val])
            candidates.append(ArxEstimate(den, nums, score))
    finite = [c for c in candidates if math.isfinite(c.validation_fit_pct)]
    if not finite:
        bound = (f" or had a pole beyond |p| < {radius:.9f} (the slowest allowed time "
                 "constant)" if radius < 1.0 else "")
        raise ValueError(f"every ARX candidate was unstable{bound}: the record does not "
                         "determine a model (too short, or no input variation)")
    best = max(c.validation_fit_pct for c in finite)
    good = [c for c in finite if c.validation_fit_pct >= best - tolerance_pct]
    chosen = min(good, key=lambda c: (c.n_params, -c.validation_fit_pct))
    return refit(y, us, chosen.na, chosen.nbs, chosen.validation_fit_pct, seg), candidates


def refit(y: FloatArray, inputs: Sequence[FloatArray], na: int, nbs: Sequence[int],
          validation_fit_pct: float = math.nan, segments: Segments | None = None
          ) -> ArxEstimate:
    """ARX least squares of one structure on the whole record (every segment)."""
    seg = segments if segments is not None else Segments.single(y.size)
    nb_max = max(nbs)
    phi = regressors(y, inputs, na, nb_max, seg)
    cols = _columns(na, nbs, na, nb_max)
    lag = max(na, nb_max - 1)
    rows, _ = seg.head_mask(lag, 0.0)
    a = phi[rows][:, cols]
    scale = np.sqrt(np.mean(a ** 2, axis=0))
    scale[scale == 0.0] = 1.0
    theta, *_ = np.linalg.lstsq(a / scale, y[rows], rcond=None)
    den, nums = _split(theta / scale, na, nbs)
    return ArxEstimate(den, nums, validation_fit_pct)


def naive_select(y: FloatArray, inputs: Sequence[FloatArray], na_range: tuple[int, int],
                 nb_range: tuple[int, int], *, validation: float = 0.3) -> list[ArxEstimate]:
    """The textbook loop (the benchmark's peer): per combination, build its own
    regression matrix and call `numpy.linalg.lstsq`, then score it the same way."""
    n = y.size
    out: list[ArxEstimate] = []
    for na in range(na_range[0], na_range[1] + 1):
        for nbs in itertools.product(range(nb_range[0], nb_range[1] + 1), repeat=len(inputs)):
            lag = max(na, max(nbs) - 1)
            n_train = max(lag + 1, round(n * (1.0 - validation)))
            blocks = [-lagged(y, na, start=1)] + [lagged(u, nb)
                                                   for u, nb in zip(inputs, nbs, strict=True)]
            phi = np.hstack(blocks)
            theta, *_ = np.linalg.lstsq(phi[lag:n_train], y[lag:n_train], rcond=None)
            den, nums = _split(np.asarray(theta, dtype=np.float64), na, nbs)
            score = -math.inf
            if is_stable(den):
                score = fit_pct(y[n_train:], simulate_common(den, nums, inputs)[n_train:])
            out.append(ArxEstimate(den, nums, score))
    return out
