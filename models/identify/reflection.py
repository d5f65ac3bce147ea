"""Stable denominators as reflection coefficients (Schur–Cohn / Levinson
step-up), the parametrisation every output-error fit keeps its poles with.

A monic polynomial B = [1, b1, …, bm] is stable (every root |p| < 1) exactly
when each of its reflection coefficients κ_i has |κ_i| < 1: a box that an
optimiser can keep (or, through κ = tanh φ, an unconstrained φ). A slowest
allowed pole (`radius` < 1, from a longest time constant, see
`models.identify.segments.pole_radius`) is kept the same way: the
denominator is the step-up polynomial with its i-th coefficient scaled by
radius^i (`scaled`), whose roots are radius × (roots with |κ| < 1).

The step-up polynomial is multilinear in κ, so central differences of it
with any step are exact (the output-error Jacobian chains through them).

Worked number: κ = (-0.95,) steps up to B = [1, -0.95], a pole at 0.95;
scaled to radius 0.9, [1, -0.855], a pole at 0.855.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


def step_up(kappa: Sequence[float] | FloatArray) -> FloatArray:
    """Monic polynomial [1, b1, …, bm] from reflection coefficients."""
    a = np.array([1.0])
    for k in kappa:
        ext = np.append(a, 0.0)
        a = ext + k * ext[::-1]
    return a


def step_down(den: Sequence[float] | FloatArray) -> FloatArray:
    """Reflection coefficients of a monic polynomial (|κ| < 1 iff stable);
    a coefficient reaching ±1 is clipped just inside (an unstable start)."""
    a = np.asarray(den, dtype=np.float64) / float(den[0])
    m = a.size - 1
    out = np.zeros(m)
    for i in range(m, 0, -1):
        k = float(np.clip(a[i], -1.0 + 1e-9, 1.0 - 1e-9))
        out[i - 1] = k
        a = (a[:i] - k * a[i:0:-1]) / (1.0 - k * k)
    return out


def scaled(poly: FloatArray, radius: float) -> FloatArray:
    """[p0, p1·r, p2·r², …]: the roots scaled by r."""
    return poly * radius ** np.arange(poly.size)


def to_kappa(den: Sequence[float], radius: float = 1.0) -> FloatArray:
    """Reflection coefficients of `den` within the radius parametrisation."""
    d = np.asarray(den, dtype=np.float64)
    return step_down(scaled(d / d[0], 1.0 / radius))
