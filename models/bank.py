"""A bank of independent transfer functions of one order, stepped together.

For many channels (a fleet of machines, or many candidate models during a
fit) one numpy DF2T step advances all N filters at once: the same arithmetic
as `TransferFunction.step`, column by column, in float64.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from models.errors import ModelError
from models.tf import TransferFunction

FloatArray = npt.NDArray[np.float64]


class TfBank:
    """N filters with numerators ``num`` (N, n+1) and denominators ``den`` (N, n+1),
    den[:, 0] == 1 (normalised). `step(u)` takes and returns arrays of shape (N,)."""

    def __init__(self, num: npt.ArrayLike, den: npt.ArrayLike) -> None:
        b = np.array(num, dtype=np.float64, ndmin=2)
        a = np.array(den, dtype=np.float64, ndmin=2)
        if b.shape != a.shape or b.shape[1] < 1:
            raise ModelError(f"bank: numerator {b.shape} and denominator {a.shape} must "
                             "have the same (N, order+1) shape")
        if not np.all(np.isfinite(b)) or not np.all(np.isfinite(a)):
            raise ModelError("bank: coefficients must be finite")
        if np.any(a[:, 0] == 0.0):
            raise ModelError("bank: a filter has b0 = 0")
        b = b / a[:, :1]
        a = a / a[:, :1]
        # row-major per coefficient: (n+1, N) so each update is a contiguous vector op
        self._b = np.ascontiguousarray(b.T)
        self._a = np.ascontiguousarray(a.T)
        self.n = b.shape[1] - 1
        self.size = b.shape[0]
        self._z = np.zeros((max(self.n, 1), self.size), dtype=np.float64)
        self._tmp = np.empty(self.size, dtype=np.float64)
        self._y = np.empty(self.size, dtype=np.float64)

    @classmethod
    def from_filters(cls, filters: Sequence[TransferFunction]) -> TfBank:
        order = max(f.order for f in filters)

        def pad(c: tuple[float, ...]) -> list[float]:
            return list(c) + [0.0] * (order + 1 - len(c))
        return cls([pad(f.num) for f in filters], [pad(f.den) for f in filters])

    def reset(self) -> None:
        self._z[:] = 0.0

    def step(self, u: FloatArray) -> FloatArray:
        """Advance every filter one sample; the returned array is reused next call."""
        b, a, z, y, tmp, n = self._b, self._a, self._z, self._y, self._tmp, self.n
        np.multiply(b[0], u, out=y)
        if n == 0:
            return y
        y += z[0]
        for i in range(n - 1):
            np.multiply(b[i + 1], u, out=z[i])
            z[i] += z[i + 1]
            np.multiply(a[i + 1], y, out=tmp)
            z[i] -= tmp
        np.multiply(b[n], u, out=z[n - 1])
        np.multiply(a[n], y, out=tmp)
        z[n - 1] -= tmp
        return y
