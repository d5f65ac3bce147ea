"""A record's rows in blocks: filters and lags carried across, normal
equations accumulated, so no regressor matrix of every row is ever built.

The identification's regressors are lagged and filtered copies of a few
signals. Built for every row at once, a month at 1 s (2.6 M rows) with 25
regressors is 520 MB per copy. Here the rows are taken a block at a time,
in order (`row_blocks`):

- `SegFilter` runs ``lfilter(b, a, ·)`` over consecutive blocks, carrying the
  filter's state (``zi``) from one block to the next and restarting from
  rest at every record's start, as `Segments.filter` does: the same numbers,
  to the last bit, as one call over the whole record;
- `SegLags` keeps the last samples of a signal so that its lagged copies
  (`Segments.shift`) are cut from the block with what came before it, zero
  before a record's start;
- `solve_blocks` solves the column-scaled normal equations accumulated over
  the blocks (float64).

A record of at most `BLOCK_ROWS` rows is one block, and then every product
and sum is the very call made over the whole record: a day at 1 s (86,400
rows) fits to the same digits as before the rows were blocked. Over
several blocks the sums are taken block by block (the same figures to
rounding).

Worked number: 100,000 rows are one block; 300,000 rows are ten blocks of
32,768 rows and one of 5,088.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Iterator, Sequence

import numpy as np
import numpy.typing as npt

from models.identify.filter_kernel import filter_zi
from models.identify.segments import Segments

FloatArray = npt.NDArray[np.float64]

#: a record of at most this many rows is one block (a day at 1 s: the numbers of
#: an unblocked fit) ...
BLOCK_ROWS = 1 << 17
#: ... a longer one goes in blocks of this many (the block's own regressors and
#: their scaled copies stay a few MB)
STREAM_ROWS = 1 << 15


def row_blocks(n: int, size: int | None = None) -> Iterator[tuple[int, int]]:
    """(lo, hi) of consecutive blocks of `size` rows (default: one block up to
    `BLOCK_ROWS` rows, else blocks of `STREAM_ROWS`)."""
    step = size if size is not None else n if n <= BLOCK_ROWS else STREAM_ROWS
    for lo in range(0, n, max(step, 1)):
        yield lo, min(n, lo + step)


def _pieces(seg: Segments, lo: int, hi: int) -> Iterator[tuple[int, int, bool]]:
    """(start, end, at a record's start) of each record's rows within [lo, hi)."""
    for s, e in seg.bounds:
        a, b = max(s, lo), min(e, hi)
        if a < b:
            yield a, b, a == s


class SegFilter:
    """``lfilter(b, a, x)`` over consecutive blocks of the concatenated records,
    restarted from rest at each record's start (`Segments.filter`, block by
    block: the same numbers)."""

    def __init__(self, seg: Segments, b: Sequence[float] | FloatArray,
                 a: Sequence[float] | FloatArray) -> None:
        self.seg = seg
        self.b = np.asarray(b, dtype=np.float64)
        self.a = np.asarray(a, dtype=np.float64)
        self.zi = np.zeros(max(self.a.size, self.b.size) - 1)

    def __call__(self, x: FloatArray, lo: int) -> FloatArray:
        """The filtered block x (rows lo … lo + len(x) - 1)."""
        pieces = list(_pieces(self.seg, lo, lo + x.size))
        if len(pieces) == 1 and pieces[0][:2] == (lo, lo + x.size):  # one record's rows
            zi = np.zeros_like(self.zi) if pieces[0][2] else self.zi
            out, self.zi = filter_zi(self.b, self.a, x, zi)  # the filter's own output
            return out
        out = np.empty_like(x, dtype=np.float64)
        for a, b, first in pieces:
            zi = np.zeros_like(self.zi) if first else self.zi
            out[a - lo:b - lo], self.zi = filter_zi(self.b, self.a, x[a - lo:b - lo], zi)
        return out


class SegLags:
    """Lagged copies of a signal given block by block: x(k - d) within each
    record, zero before its start (`Segments.shift`), for d ≤ `lags`."""

    def __init__(self, seg: Segments, lags: int) -> None:
        self.seg, self.lags = seg, lags
        self._ext = np.zeros(lags)
        self._lo = 0

    def feed(self, x: FloatArray, lo: int) -> None:
        """The next block (rows lo …), after the one fed before."""
        self._ext = np.concatenate([self._ext[self._ext.size - self.lags:], x])
        self._lo = lo

    def shift(self, d: int, out: FloatArray | None = None) -> FloatArray:
        """x(k - d) over the block fed last (written into `out` when given)."""
        m = self._ext.size - self.lags
        if out is None:
            out = self._ext[self.lags - d:self.lags - d + m].copy()
        else:
            out[:] = self._ext[self.lags - d:self.lags - d + m]
        lo = self._lo
        for s, _ in self.seg.bounds:  # zero within d rows of a record's start
            a, b = max(s, lo), min(s + d, lo + m)
            if a < b:
                out[a - lo:b - lo] = 0.0
        return out


def solve_blocks(blocks: Iterable[tuple[FloatArray, FloatArray]]) -> FloatArray:
    """Least squares of b on the columns of a, the (a, b) rows given in blocks,
    through the column-scaled normal equations (`solve_one` for one block)."""
    it = iter(blocks)
    first = next(it)
    second = next(it, None)
    if second is None:  # row-major, as one stacked matrix was
        return solve_one(np.ascontiguousarray(first[0]), first[1])
    gram, rhs, sumsq, n = normal_sums(itertools.chain([first, second], it))
    scale = np.sqrt(sumsq / n)
    scale[scale == 0.0] = 1.0
    g = gram / scale[:, None] / scale[None, :]
    g[np.diag_indices_from(g)] += 1e-12 * float(np.trace(g)) / g.shape[0]
    try:
        theta = np.linalg.solve(g, rhs / scale)
    except np.linalg.LinAlgError:
        theta, *_ = np.linalg.lstsq(g, rhs / scale, rcond=None)
    return np.asarray(theta / scale, dtype=np.float64)


def normal_sums(blocks: Iterable[tuple[FloatArray, FloatArray]]
            ) -> tuple[FloatArray, FloatArray, FloatArray, int]:
    """(aᵀa, aᵀb, Σ a², rows) summed over the blocks (an iterable consumed once;
    Σ a² is aᵀa's diagonal)."""
    gram = rhs = None
    n = 0
    for a, b in blocks:
        g, r = a.T @ a, a.T @ b
        gram = g if gram is None else gram + g
        rhs = r if rhs is None else rhs + r
        n += a.shape[0]
    if gram is None or rhs is None:
        raise ValueError("no rows")
    return gram, rhs, np.diag(gram).copy(), n


def solve_one(a: FloatArray, b: FloatArray) -> FloatArray:
    """Least squares through the column-scaled normal equations (the
    regressors are few; an N-row SVD per candidate cost more than the rest)."""
    scale = np.sqrt(np.mean(a ** 2, axis=0))
    scale[scale == 0.0] = 1.0
    x = a / scale
    g = x.T @ x
    g[np.diag_indices_from(g)] += 1e-12 * float(np.trace(g)) / g.shape[0]
    try:
        theta = np.linalg.solve(g, x.T @ b)
    except np.linalg.LinAlgError:
        theta, *_ = np.linalg.lstsq(x, b, rcond=None)
    return np.asarray(theta / scale, dtype=np.float64)
