"""Several records fitted jointly as separate experiments.

A calibration may consist of several records (a heat-up/cool-down, an
environmental run): they are concatenated into one array per signal, and a
`Segments` value says where each record begins and ends. Nothing carries over
a boundary: every filter restarts from rest at a record's first sample (each
record is relative to its own first sample), and a lagged regressor is zero
before its record's start, exactly as if each record were fitted alone.

Worked example: lengths (3, 2) give bounds ((0, 3), (3, 5)); `shift` of
[1, 2, 3, 4, 5] by one sample is [0, 1, 2, 0, 4].
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Segments:
    """Half-open (start, end) index ranges of consecutive records."""

    bounds: tuple[tuple[int, int], ...]

    @classmethod
    def from_lengths(cls, lengths: Sequence[int]) -> Segments:
        if not lengths or any(n < 1 for n in lengths):
            raise ValueError(f"segment lengths must be >= 1, got {list(lengths)}")
        out: list[tuple[int, int]] = []
        start = 0
        for n in lengths:
            out.append((start, start + int(n)))
            start += int(n)
        return cls(tuple(out))

    @classmethod
    def single(cls, n: int) -> Segments:
        return cls.from_lengths([n])

    @property
    def total(self) -> int:
        return self.bounds[-1][1]

    @property
    def lengths(self) -> tuple[int, ...]:
        return tuple(e - s for s, e in self.bounds)

    def filter(self, b: Sequence[float] | FloatArray, a: Sequence[float] | FloatArray,
               x: FloatArray) -> FloatArray:
        """`lfilter(b, a, x)` restarted from rest at every segment start."""
        from models.identify.filter_kernel import lfilter_rest

        out = np.empty_like(x, dtype=np.float64)
        bb, aa = np.asarray(b, dtype=np.float64), np.asarray(a, dtype=np.float64)
        for s, e in self.bounds:
            out[s:e] = lfilter_rest(bb, aa, x[s:e])
        return out

    def shift(self, x: FloatArray, d: int) -> FloatArray:
        """x(k - d) within each segment, zero before its start."""
        if d == 0:
            return x
        out = np.zeros_like(x)
        for s, e in self.bounds:
            if e - s > d:
                out[s + d:e] = x[s:e - d]
        return out

    def lagged(self, x: FloatArray, lags: int, start: int = 0) -> FloatArray:
        """Columns x(k-start), …, x(k-start-lags+1) per segment."""
        out = np.zeros((x.size, lags))
        for j in range(lags):
            out[:, j] = self.shift(x, start + j)
        return out

    def head_mask(self, lag: int, validation: float) -> tuple[npt.NDArray[np.bool_],
                                                           npt.NDArray[np.bool_]]:
        """(train, validation) row masks: in each segment the rows after the
        first `lag` up to the last `validation` fraction train; that tail
        validates."""
        train = np.zeros(self.total, dtype=bool)
        val = np.zeros(self.total, dtype=bool)
        for s, e in self.bounds:
            n_train = max(lag + 1, round((e - s) * (1.0 - validation)))
            train[s + lag:min(e, s + n_train)] = True
            val[s + n_train:e] = True
        return train, val

    def heads(self, validation: float) -> Segments:
        """The segments cut to their first (1 - validation) fraction."""
        return Segments.from_lengths([max(1, round(n * (1.0 - validation)))
                                      for n in self.lengths])

    def take_heads(self, x: FloatArray, validation: float) -> FloatArray:
        """x restricted to `heads(validation)`, concatenated."""
        parts = [x[s:s + n] for (s, _), n in zip(self.bounds, self.heads(validation).lengths,
                                                 strict=True)]
        return np.concatenate(parts)


def pole_radius(period_s: float | None, max_time_constant_s: float | None) -> float:
    """The largest pole magnitude allowed: a real pole p has the time constant
    -period_s / ln p, so τ ≤ τ_max means |p| ≤ exp(-period_s / τ_max).
    1.0 (only strictly stable) when either is unknown.

    Worked number: 10 s sampling and τ_max = 3 days give 0.9999614."""
    if period_s is None or max_time_constant_s is None:
        return 1.0
    if not (period_s > 0.0 and max_time_constant_s > 0.0):
        raise ValueError("period_s and max_time_constant_s must be > 0")
    return float(np.exp(-period_s / max_time_constant_s))
