"""The estimators a structure search trains on a fold's rows: the shared-
denominator ARX least squares, refined by Steiglitz–McBride (`arx_fit`),
output error from it (`_oe`), ridge numerators over the shared-oe
denominator (`_ridge`), the static model (`_static_fit`), and every
structure asked for at once (`_fold_models`).
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator, Sequence

import numpy as np
import numpy.typing as npt

from models.identify.arx import is_stable
from models.identify.blocks import SegFilter, SegLags, normal_sums, row_blocks, solve_blocks
from models.identify.fold_data import _Data, rows_key
from models.identify.output_error import OeModel, counted_end, output_error_model
from models.identify.segments import Segments
from models.identify.validate import forced_response

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

#: ridge penalties tried, relative to the mean squared regressor (scaled columns)
RIDGE_GRID: tuple[float, ...] = (1e-4, 1e-3, 1e-2, 1e-1)
#: output-error iterations stop when one gains less than this share of the cost
OE_TOL = 1e-4
#: Steiglitz–McBride iterations of the order search
SM_ITERATIONS = 4


def _lag_ok(mask: BoolArray, seg: Segments, lag: int) -> BoolArray:
    """Rows whose `lag` predecessors are all in `mask` and in the same record."""
    ok = mask.copy()
    for d in range(1, lag + 1):
        for s, e in seg.bounds:  # mask(k - d) within the record, False before its start
            ok[s:min(e, s + d)] = False
            if e - s > d:
                ok[s + d:e] &= mask[s:e - d]
    return ok


def arx_fit(d: _Data, na: int, nb: int, train: BoolArray, iterations: int = 0
            ) -> OeModel | None:
    """Shared-denominator ARX by least squares; with `iterations` > 0 refined
    by Steiglitz–McBride (y and u filtered by 1/B̂ of the previous estimate,
    least squares again: it converges towards the output-error estimate, so
    orders chosen with it are not those of the noise-biased ARX). With the
    initial conditions estimated, shifts of a record indicator (filtered the
    same way) join the regressors. None if unstable. Memoised on `d`
    (`_Data.arx_memo`); Steiglitz–McBride starts from the memoised ARX
    estimate (its first iteration, the same least squares), and leaves it
    there for the ARX candidate."""
    rows = rows_key(train)
    key = (na, nb, iterations, d.initial, rows)
    if key in d.arx_memo:
        return d.arx_memo[key]
    first = (na, nb, 0, d.initial, rows)
    if first in d.arx_memo and d.arx_memo[first] is None:  # no ARX: no refinement either
        d.arx_memo[key] = None
        return None
    result, arx = _arx_fit(d, na, nb, train, iterations, d.arx_memo.get(first))
    d.arx_memo[key] = result
    d.arx_memo[first] = arx
    return result


def _arx_fit(d: _Data, na: int, nb: int, train: BoolArray, iterations: int,
             arx: OeModel | None = None) -> tuple[OeModel | None, OeModel | None]:
    """(`arx_fit`'s estimate, the ARX least squares it started from), the
    latter taken from `arx` when given (then not computed again)."""
    seg = d.seg
    lag = max(na, nb - 1)
    rows = _lag_ok(train, seg, lag)
    den: tuple[float, ...] = (1.0,)
    nums: tuple[tuple[float, ...], ...] = ()
    n_cols = na + len(d.us) * nb + (len(seg.bounds) * (lag + 1) if d.initial else 0)
    start = 0
    if arx is not None:
        den, nums, start = arx.dens[0], arx.nums, 1
    for it in range(start, iterations + 1):
        if int(rows.sum()) <= n_cols:  # fewer rows than parameters: nothing determined
            return None, None
        y = d.y if it == 0 else _known(d, nums, den)
        theta = solve_blocks(_arx_blocks(d, y, na, nb, lag, den if it else None, rows))
        new_den = (1.0, *(float(v) for v in theta[:na]))
        if not is_stable(new_den, d.radius):
            if it == 0:
                return None, None
            break
        den = new_den
        nums = tuple(tuple(float(v) for v in theta[na + t * nb:na + (t + 1) * nb])
                     for t in range(len(d.us)))
        if it == 0:
            arx = OeModel(nums=nums, dens=(den,), groups=(tuple(range(len(d.us))),))
    return OeModel(nums=nums, dens=(den,), groups=(tuple(range(len(d.us))),)), arx


def _known(d: _Data, nums: tuple[tuple[float, ...], ...], den: tuple[float, ...]
           ) -> FloatArray:
    """The displacement to prefilter: on rows outside the usable ones (never to be seen) the
    estimate's own simulation instead, so that a filter's memory carries none
    of them into the rows after."""
    if d.usable is None or not nums:
        return d.y
    sim = forced_response(nums, (den,), (tuple(range(len(d.us))),), d.us, d.seg)
    return np.where(d.usable, d.y, sim)


def _arx_blocks(d: _Data, y: FloatArray, na: int, nb: int, lag: int,
                den: Sequence[float] | None, rows: BoolArray
                ) -> Iterator[tuple[FloatArray, FloatArray]]:
    """`arx_fit`'s (regressors, target) over the `rows`, block by block
    (`models.identify.blocks`): [-fy(k-1) … -fy(k-na) | fu_t(k) … fu_t(k-nb+1)
    per input | a record indicator's shifts 0 … lag per record], fy (of `y`: the
    displacement, or `_known`'s) and fu filtered by 1/den (`den` None: unfiltered).
    Nothing is filtered past the last of the `rows` (the filters are causal: the
    rows before are the same to the bit); a block after it is empty."""
    seg = d.seg
    sigs = [y, *d.us]
    filters = [SegFilter(seg, [1.0], den) if den is not None else None for _ in sigs]
    lags = [SegLags(seg, lag) for _ in sigs]
    n_init = len(seg.bounds) if d.initial else 0
    ind_filters = [SegFilter(seg, [1.0], den) if den is not None else None
                   for _ in range(n_init)]
    ind_lags = [SegLags(seg, lag) for _ in range(n_init)]
    p = na + len(d.us) * nb + n_init * (lag + 1)
    end = counted_end(rows)
    for lo, full in row_blocks(y.size):
        if lo >= end:  # no row of the fit here or after: nothing filtered
            yield np.empty((0, p)), y[lo:lo]
            continue
        hi = min(full, end)
        x = np.empty((p, hi - lo))  # a regressor per row: each filled contiguously
        fy = y[lo:hi]
        for k, (sig, f, lg) in enumerate(zip(sigs, filters, lags, strict=True)):
            fb = sig[lo:hi] if f is None else f(sig[lo:hi], lo)
            if k == 0:
                fy = fb
            lg.feed(fb, lo)
        for i in range(1, na + 1):
            np.negative(lags[0].shift(i, x[i - 1]), out=x[i - 1])
        col = na
        for lg in lags[1:]:
            for j in range(nb):
                lg.shift(j, x[col])
                col += 1
        for r, (s, e) in enumerate(seg.bounds[:n_init]):
            ind = np.zeros(hi - lo)
            ind[max(s, lo) - lo:max(min(e, hi) - lo, 0)] = 1.0
            f = ind_filters[r]
            ind_lags[r].feed(ind if f is None else f(ind, lo), lo)
            for j in range(lag + 1):
                ind_lags[r].shift(j, x[col])
                col += 1
        keep = rows[lo:hi]
        if keep.all():  # every row: the regressors themselves, not a copy
            yield x.T, fy
        else:
            yield x[:, keep].T, fy[keep]


def _sm(d: _Data, na: int, nb: int, train: BoolArray) -> OeModel | None:
    return arx_fit(d, na, nb, train, SM_ITERATIONS)


def _oe(d: _Data, start: OeModel | None, train: BoolArray, per_term: bool,
        max_iter: int) -> OeModel | None:
    if start is None:
        return None
    groups = [(t,) for t in range(len(d.us))] if per_term else [tuple(range(len(d.us)))]
    dens = [start.dens[0]] * len(groups)
    return output_error_model(d.y, d.us, start.nums, dens, groups, mask=train, segments=d.seg,
                              radius=d.radius, max_iter=max_iter, init0=start.init or None,
                              tol=OE_TOL, initial=d.initial)


def _ridge(d: _Data, shared: OeModel | None, train: BoolArray, lam: float) -> OeModel | None:
    """Numerators by ridge on u_t/B over `shared`'s denominator. Only each
    input's gain Σ_j a_tj is penalised (the direction in which correlated
    sensors cancel); the shape of each numerator stays free (penalising the
    raw coefficients destroyed the near-differencing numerators of slow
    terms: 75 % instead of 97.6 % validation on the SP3 record)."""
    if shared is None:
        return None
    den = shared.dens[0]
    nb = len(shared.nums[0])
    n_num = len(d.us) * nb
    blocks = _ridge_blocks(d, den, nb, train)
    first = next(blocks)
    second = next(blocks, None)
    if second is None:  # one block: the scaled rows themselves (row-major, as stacked)
        a = np.ascontiguousarray(first[0])
        scale = np.sqrt(np.mean(a ** 2, axis=0))
        scale[scale == 0.0] = 1.0
        a = a / scale
        gram = a.T @ a
        rhs = a.T @ first[1]
        n = a.shape[0]
    else:
        g, r, sumsq, n = normal_sums(itertools.chain([first, second], blocks))
        scale = np.sqrt(sumsq / n)
        scale[scale == 0.0] = 1.0
        gram = g / scale[:, None] / scale[None, :]
        rhs = r / scale
    pen = np.full(gram.shape[0], 1e-12 * float(np.trace(gram)) / gram.shape[0])
    pen[:n_num:nb] += lam * n
    try:
        theta = np.linalg.solve(gram + np.diag(pen), rhs) / scale
    except np.linalg.LinAlgError:
        return None
    nums = []
    for t in range(len(d.us)):
        gain, rest = theta[t * nb], theta[t * nb + 1:(t + 1) * nb]
        nums.append((float(gain - rest.sum()), *(float(v) for v in rest)))
    return OeModel(nums=tuple(nums), dens=(den,), groups=shared.groups)


def _ridge_blocks(d: _Data, den: Sequence[float], nb: int, train: BoolArray
                  ) -> Iterator[tuple[FloatArray, FloatArray]]:
    """`_ridge`'s (regressors, target) over the `train` rows, block by block:
    per input w = u/B, then w(k-j) - w(k) for j = 1 … nb-1; with the initial
    conditions, per record its indicator and the shifts 0 … nb-1 of the
    indicator filtered by 1/B. Nothing is filtered past the last `train` row (as
    `_arx_blocks`)."""
    seg = d.seg
    filters = [SegFilter(seg, [1.0], den) for _ in d.us]
    lags = [SegLags(seg, nb) for _ in d.us]
    n_init = len(seg.bounds) if d.initial else 0
    ind_filters = [SegFilter(seg, [1.0], den) for _ in range(n_init)]
    ind_lags = [SegLags(seg, nb) for _ in range(n_init)]
    p = len(d.us) * nb + n_init * (nb + 1)
    end = counted_end(train)
    for lo, full in row_blocks(d.y.size):
        if lo >= end:  # no row of the fit here or after: nothing filtered
            yield np.empty((0, p)), d.y[lo:lo]
            continue
        hi = min(full, end)
        x = np.empty((p, hi - lo))  # a regressor per row: each filled contiguously
        col = 0
        for u, f, lg in zip(d.us, filters, lags, strict=True):
            w = f(u[lo:hi], lo)
            lg.feed(w, lo)
            x[col] = w
            for j in range(1, nb):
                x[col + j] = lg.shift(j) - w
            col += nb
        for r, (s, e) in enumerate(seg.bounds[:n_init]):
            ind = np.zeros(hi - lo)
            ind[max(s, lo) - lo:max(min(e, hi) - lo, 0)] = 1.0
            ind_lags[r].feed(ind_filters[r](ind, lo), lo)
            x[col] = ind
            for j in range(nb):
                x[col + 1 + j] = ind_lags[r].shift(j)
            col += nb + 1
        keep = train[lo:hi]
        if keep.all():  # every row: the regressors themselves, not a copy
            yield x.T, d.y[lo:hi]
        else:
            yield x[:, keep].T, d.y[lo:hi][keep]


def _static_fit(d: _Data, train: BoolArray) -> OeModel | None:
    """y = Σ k_t u_t + a level per record, least squares on `train` rows."""
    cols = list(d.us)
    for s, e in d.seg.bounds:
        ind = np.zeros(d.y.size)
        ind[s:e] = 1.0
        cols.append(ind)
    if int(train.sum()) < len(cols):
        return None
    theta = solve_blocks((np.stack([c[lo:hi] for c in cols], axis=1)[train[lo:hi]],
                          d.y[lo:hi][train[lo:hi]]) for lo, hi in row_blocks(d.y.size))
    return OeModel(nums=tuple((float(k),) for k in theta[:len(d.us)]), dens=((1.0,),),
                   groups=(tuple(range(len(d.us))),))


def _fold_models(d: _Data, na: int, nb: int, train: BoolArray, structures: Sequence[str],
                 max_iter: int, arx_at: tuple[int, int] | None = None, per_term: bool = True
                 ) -> dict[str, OeModel | None]:
    """Every structure (ridge: every λ) trained on `train`; the ARX least
    squares at `arx_at` (default the same orders). Without `per_term`,
    per-term-oe is left out and shared-oe is kept (its start) even when not
    asked for."""
    out: dict[str, OeModel | None] = {}
    arx = arx_fit(d, *(arx_at or (na, nb)), train)
    out["arx"] = arx
    sm = arx_fit(d, na, nb, train, SM_ITERATIONS) if set(structures) - {"arx"} else None
    shared = _oe(d, sm, train, False, max_iter)
    if "shared-oe" in structures or not per_term:
        out["shared-oe"] = shared
    if "ridge" in structures:
        for lam in RIDGE_GRID:
            out[f"ridge:{lam:g}"] = _ridge(d, shared, train, lam)
    if "per-term-oe" in structures and per_term:
        # from the shared-oe estimate: the same output, a far better basin than
        # the ARX start (a day at 1 s: 23,600 µm² instead of 270,000 at the start)
        out["per-term-oe"] = _oe(d, shared, train, True, max_iter)
    return out
