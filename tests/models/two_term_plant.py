"""A small identification case shared by the fit's cost and counted-rows tests: two
first-order terms on two heated sensors, with probe noise, as the simulation fits."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


def two_term_plant(n: int = 1500) -> tuple[FloatArray, list[FloatArray]]:
    """(displacement, [sensor 1, sensor 2]) over `n` samples; the same every call."""
    rng = np.random.default_rng(5)
    k = np.arange(n)
    u1 = 5.0 * (1.0 - np.exp(-k / 200.0)) + 0.5 * np.sin(k / 90.0)
    u2 = 3.0 * (1.0 - np.exp(-k / 500.0)) * (1.0 + 0.3 * np.sin(k / 150.0))
    y = np.zeros(n)
    x1 = x2 = 0.0
    for i in range(n):
        x1 = 0.97 * x1 + 0.03 * 2.0 * u1[i]
        x2 = 0.99 * x2 + 0.01 * -1.5 * u2[i]
        y[i] = x1 + x2
    return y + 0.05 * rng.standard_normal(n), [u1, u2]
