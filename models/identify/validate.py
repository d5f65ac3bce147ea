"""Blocked cross-validation of a linear model structure on records that may
start warm.

Each record is cut into `k + 1` contiguous blocks; fold f holds out block
f + 1 of every record. The first block always trains: a record that starts
warm has initial conditions that only its beginning determines (with the
first block held out, per-term levels fitted on later rows extrapolated
backwards to -25,000 % on the 48 h split). A candidate is trained on the
other rows and then *simulated from the record's start* over the whole record (its inputs are known
everywhere; only the held-out displacement is hidden); the initial
conditions (a level per record, and a level per input, see
`models.identify.output_error`) are estimated by least squares on the
training rows only, and the held-out rows are scored. The pooled figure is

    fit % = (1 - sqrt(Σ_f ‖y_f - ŷ_f‖²) / sqrt(Σ_f ‖y_f - mean(y_f)‖²)) · 100

(each block measured against its own mean: a fold of a flat stretch weighs
little instead of dominating with a huge negative figure).

Worked number: 2 folds of a 9-sample record hold out rows 3-5 and 6-8.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator, Sequence

import numpy as np
import numpy.typing as npt

from models.identify.blocks import SegFilter, normal_sums, row_blocks
from models.identify.segments import Segments

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]


def fold_masks(seg: Segments, k: int) -> list[BoolArray]:
    """Held-out rows of each of `k` folds (block f + 1 of every record)."""
    if k < 2:
        raise ValueError(f"cross-validation needs at least 2 folds, got {k}")
    out = [np.zeros(seg.total, dtype=bool) for _ in range(k)]
    for s, e in seg.bounds:
        edges = np.linspace(s, e, k + 2).round().astype(int)
        for f in range(k):
            out[f][edges[f + 1]:edges[f + 2]] = True
    return out


def forward_masks(seg: Segments, k: int) -> list[tuple[BoolArray, BoolArray]]:
    """(training rows, held-out rows) of `k` forward folds: the held-out
    blocks of `fold_masks`, each trained only on the rows of its record that
    come *before* it (rolling origin). A model is used on what follows its
    calibration, under speeds and rooms it has not seen; training on the rows
    after a block lets a candidate interpolate a regime it will have to
    extrapolate (the real record's ch4: 91.8 % on blocked folds, 70.8 % on the
    day that followed)."""
    held = fold_masks(seg, k)
    out: list[tuple[BoolArray, BoolArray]] = []
    for val in held:
        train = np.zeros(seg.total, dtype=bool)
        for s, e in seg.bounds:
            hit = np.flatnonzero(val[s:e])
            if hit.size:
                train[s:s + int(hit[0])] = True
        out.append((train, val))
    return out


def split_masks(seg: Segments, k: int, scheme: str) -> list[tuple[BoolArray, BoolArray]]:
    """(training, held-out) rows per fold of a validation `scheme`: ``blocked``
    (train on every other block), ``forward`` (`forward_masks`) or ``both``
    (the two sets of folds pooled)."""
    if scheme == "blocked":
        return [(~v, v) for v in fold_masks(seg, k)]
    if scheme == "forward":
        return forward_masks(seg, k)
    if scheme == "both":
        return [(~v, v) for v in fold_masks(seg, k)] + forward_masks(seg, k)
    raise ValueError(f"unknown validation scheme {scheme!r}; known: blocked, forward, both")


def usable_splits(seg: Segments, k: int, scheme: str, usable: BoolArray | None
                  ) -> list[tuple[BoolArray, BoolArray]]:
    """`split_masks` over the rows a loss may count (`usable`: a calibration
    window, less any rows held out), laid over those rows in order as if the
    others were cut out: each record's first usable rows always train, a forward
    fold trains on the usable rows before its block, and no fold trains on or
    scores a row outside `usable`. Those rows still run through the simulation,
    which starts at each record's start (`forced_response`). None: `split_masks`
    itself.

    Worked number: a 10-row record usable from row 4, 2 forward folds: blocks
    4-5, 6-7, 8-9; fold 1 trains on 4-5 and scores 6-7. Rows 6-7 masked as well:
    blocks 4, then 5 and 8, then 9."""
    if usable is None:
        return split_masks(seg, k, scheme)
    usable = np.asarray(usable, dtype=bool)
    if usable.shape != (seg.total,):
        raise ValueError("the usable rows must mark each row of the records")
    lengths = [int(usable[s:e].sum()) for s, e in seg.bounds]
    if min(lengths) < k + 1:
        raise ValueError(f"a record has {min(lengths)} usable rows, too few for {k + 1} "
                         "blocks")
    rows = np.flatnonzero(usable)
    out: list[tuple[BoolArray, BoolArray]] = []
    for train_u, val_u in split_masks(Segments.from_lengths(lengths), k, scheme):
        train = np.zeros(seg.total, dtype=bool)
        val = np.zeros(seg.total, dtype=bool)
        train[rows[train_u]] = True
        val[rows[val_u]] = True
        out.append((train, val))
    return out


def forced_response(nums: Sequence[Sequence[float]], dens: Sequence[Sequence[float]],
                    groups: Sequence[Sequence[int]], inputs: Sequence[FloatArray],
                    seg: Segments, end: int | None = None) -> FloatArray:
    """Σ_g (Σ_{t∈g} A_t u_t) / B_g from rest at every record's start (block by
    block, `models.identify.blocks`: only the sum is of every row). With `end`,
    the rows before it only (the filters are causal: the same to the bit), 0
    after it."""
    total = np.zeros(inputs[0].size)
    firs = {t: SegFilter(seg, np.asarray(nums[t], dtype=np.float64), [1.0])
            for members in groups for t in members}
    iirs = [SegFilter(seg, [1.0], np.asarray(b, dtype=np.float64)) for b in dens]
    stop = total.size if end is None else end
    for lo, full in row_blocks(total.size):
        if lo >= stop:
            break
        hi = min(full, stop)
        for g, members in enumerate(groups):
            v = np.zeros(hi - lo)
            for t in members:
                v += firs[t](inputs[t][lo:hi], lo)
            total[lo:hi] += iirs[g](v, lo)
    return total


def initial_basis(nums: Sequence[Sequence[float]], dens: Sequence[Sequence[float]],
                  groups: Sequence[Sequence[int]], seg: Segments) -> FloatArray:
    """Columns per record: its level indicator, then each term's response to
    a unit step at the record's start (a term relaxing from a steady state,
    see `models.output_error`)."""
    n = seg.total
    cols: list[FloatArray] = []
    for s, e in seg.bounds:
        ind = np.zeros(n)
        ind[s:e] = 1.0
        cols.append(ind)
        for g, members in enumerate(groups):
            for t in members:
                cols.append(seg.filter(np.asarray(nums[t], dtype=np.float64),
                                       np.asarray(dens[g], dtype=np.float64), ind))
    return np.stack(cols, axis=1)


def _basis_blocks(nums: Sequence[Sequence[float]], dens: Sequence[Sequence[float]],
                  groups: Sequence[Sequence[int]], seg: Segments, end: int | None = None
                  ) -> Iterator[tuple[int, int, FloatArray]]:
    """`initial_basis`'s rows block by block (`models.identify.blocks`); with
    `end`, the rows from it on 0 (nothing filtered there), every block still
    handed on."""
    filters = [[SegFilter(seg, np.asarray(nums[t], dtype=np.float64),
                          np.asarray(dens[g], dtype=np.float64))
                for g, members in enumerate(groups) for t in members] for _ in seg.bounds]
    per = 1 + sum(len(m) for m in groups)
    stop = seg.total if end is None else end
    for lo, full in row_blocks(seg.total):
        out = np.zeros((full - lo, per * len(seg.bounds)))
        hi = max(lo, min(full, stop))
        for r, (s, e) in enumerate(seg.bounds if hi > lo else ()):
            ind = np.zeros(hi - lo)
            ind[max(s, lo) - lo:max(min(e, hi) - lo, 0)] = 1.0
            out[:hi - lo, r * per] = ind
            for c, f in enumerate(filters[r]):
                out[:hi - lo, r * per + 1 + c] = f(ind, lo)
        yield lo, full, out


def with_initial(y: FloatArray, forced: FloatArray, nums: Sequence[Sequence[float]],
                 dens: Sequence[Sequence[float]], groups: Sequence[Sequence[int]],
                 seg: Segments, train: BoolArray, end: int | None = None) -> FloatArray:
    """`forced` plus the initial-condition response fitted on `train` rows
    (least squares on the scaled basis; over several blocks through its
    normal equations, the basis built block by block twice). With `end` (past
    the last `train` row), the rows before it only: the same to the bit, the
    rows after it not made (as `forced_response` with `end`)."""
    blocks = _basis_blocks(nums, dens, groups, seg, end)
    lo, hi, basis = next(blocks)
    if hi == seg.total:  # one block: the basis itself
        a = basis[train]
        scale = np.sqrt(np.mean(a ** 2, axis=0))
        scale[scale == 0.0] = 1.0
        theta, *_ = np.linalg.lstsq(a / scale, (y - forced)[train], rcond=1e-10)
        return np.asarray(forced + basis @ (theta / scale), dtype=np.float64)
    rest = ((b[train[lo:hi]], (y[lo:hi] - forced[lo:hi])[train[lo:hi]]) for lo, hi, b in
            itertools.chain([(lo, hi, basis)], blocks))
    gram, rhs, sumsq, n = normal_sums(rest)
    scale = np.sqrt(sumsq / max(n, 1))
    scale[scale == 0.0] = 1.0
    theta, *_ = np.linalg.lstsq(gram / scale[:, None] / scale[None, :], rhs / scale,
                                rcond=1e-20)
    out = np.empty_like(forced, dtype=np.float64)
    for lo, hi, b in _basis_blocks(nums, dens, groups, seg, end):
        out[lo:hi] = forced[lo:hi] + b @ (theta / scale)
    return out


def pooled_fit(y: FloatArray, sims: Sequence[FloatArray], masks: Sequence[BoolArray]) -> float:
    """The pooled held-out fit % (module docstring); -inf if any is not finite."""
    return pooled_parts([(y[m], sim[m]) for sim, m in zip(sims, masks, strict=True)])


def pooled_parts(held: Sequence[tuple[FloatArray, FloatArray]]) -> float:
    """`pooled_fit` of the (measured, simulated) held-out rows of each fold."""
    pool = Pooled()
    for y_m, sim_m in held:
        pool.add(y_m, sim_m)
    return pool.value


class Pooled:
    """`pooled_parts` summed fold by fold: each fold's held-out rows are
    added and can be let go (a month at 1 s holds four fifths of its rows
    out, 33 MB of measured and simulated rows kept to the end otherwise)."""

    def __init__(self) -> None:
        self.err = 0.0
        self.spread = 0.0
        self.finite = True

    def add(self, y_m: FloatArray, sim_m: FloatArray) -> None:
        if not self.finite:
            return
        if not np.all(np.isfinite(sim_m)):
            self.finite = False
            return
        self.err += float(np.sum((y_m - sim_m) ** 2))
        self.spread += float(np.sum((y_m - y_m.mean()) ** 2))

    @property
    def value(self) -> float:
        """The pooled fit %; -inf when a fold was not finite or nothing varies."""
        if not self.finite or self.spread == 0.0:
            return -math.inf
        return (1.0 - math.sqrt(self.err / self.spread)) * 100.0
