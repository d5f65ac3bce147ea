"""Output-error refinement: minimise the SIMULATION error.

ARX least squares minimises the one-step prediction error, which is biased
when the displacement is measured with noise (the noisy y(k-i) sit among the
regressors). The compensation runs in simulation mode (the model never sees
the measurement), so the criterion that matters is::

    min_θ Σ_k ( y(k) - Σ_t A_t(q)/B_t(q) · u_t(k) )²

Each term gets its own denominator B_t (initialised from the ARX shared one),
so the written model is one proper SISO transfer function per term.

Stability is kept by parametrising each denominator by its reflection
coefficients κ (Schur–Cohn / Levinson step-up): B is stable exactly when
every |κ_i| < 1, a box constraint that `scipy.optimize.least_squares` keeps.
The Jacobian is exact: ∂ŷ/∂a_j = q^-j·u/B and ∂ŷ/∂b_i = -q^-i·ŷ_t/B (two
filter runs per term), chained through the step-up polynomial, which is
multilinear in κ (so central differences of it are exact).

A slowest allowed pole (`radius` < 1, from a longest time constant, see
`models.identify.segments.pole_radius`) is kept the same way: the
denominator is the step-up polynomial with its i-th coefficient scaled by
radius^i, whose poles are radius × (poles with |κ| < 1), so every pole stays
within |p| < radius. Several records (`segments`) are simulated each from
rest and their residuals stacked.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares

from models.identify.arx import fit_pct
from models.identify.segments import Segments

FloatArray = npt.NDArray[np.float64]

#: reflection coefficients are kept within ±(1 - KAPPA_MARGIN): poles strictly inside
KAPPA_MARGIN = 1e-12


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


@dataclass(frozen=True)
class OeEstimate:
    """Per-term (numerator, denominator), den[0] = 1; fit % on the record."""

    nums: tuple[tuple[float, ...], ...]
    dens: tuple[tuple[float, ...], ...]
    fit_pct: float
    iterations: int


class _Problem:
    def __init__(self, y: FloatArray, inputs: Sequence[FloatArray], nbs: Sequence[int],
                 nas: Sequence[int], segments: Segments, radius: float) -> None:
        self.y = y
        self.inputs = list(inputs)
        self.nbs = list(nbs)
        self.nas = list(nas)
        self.seg = segments
        self.radius = radius

    def unpack(self, theta: FloatArray) -> list[tuple[FloatArray, FloatArray, FloatArray]]:
        out = []
        i = 0
        for nb, na in zip(self.nbs, self.nas, strict=True):
            num = theta[i:i + nb]
            kappa = theta[i + nb:i + nb + na]
            out.append((num, kappa, scaled(step_up(kappa), self.radius)))
            i += nb + na
        return out

    def simulate(self, theta: FloatArray) -> FloatArray:
        total = np.zeros_like(self.y)
        for (num, _, den), u in zip(self.unpack(theta), self.inputs, strict=True):
            total += self.seg.filter(num, den, u)
        return total

    def residual(self, theta: FloatArray) -> FloatArray:
        return self.y - self.simulate(theta)

    def jacobian(self, theta: FloatArray) -> FloatArray:
        cols: list[FloatArray] = []
        for (num, kappa, den), u in zip(self.unpack(theta), self.inputs, strict=True):
            seg = self.seg
            w = seg.filter([1.0], den, u)
            yt = seg.filter(num, den, u)
            v = seg.filter([1.0], den, yt)
            cols += [-seg.shift(w, j) for j in range(num.size)]
            # ∂ŷ/∂b_i = -q^-i ŷ_t / B ; residual derivative is the negative
            d_den = np.stack([seg.shift(v, i) for i in range(1, den.size)], axis=1) \
                if den.size > 1 else np.zeros((u.size, 0))
            h = 0.5
            for m in range(kappa.size):
                kp, km = kappa.copy(), kappa.copy()
                kp[m] += h
                km[m] -= h
                dpoly = scaled(step_up(kp) - step_up(km), self.radius)[1:] / (2 * h)
                cols.append(d_den @ dpoly)
        return np.stack(cols, axis=1)


def refine_oe(y: FloatArray, inputs: Sequence[FloatArray], nums: Sequence[Sequence[float]],
              dens: Sequence[Sequence[float]], *, max_nfev: int = 200,
              tol: float = 1e-12, segments: Segments | None = None,
              radius: float = 1.0) -> OeEstimate:
    """Output-error fit starting from (nums, dens), one pair per input; every
    pole kept within |p| < `radius` (≤ 1); `segments`: several records."""
    y = np.asarray(y, dtype=np.float64)
    us = [np.asarray(u, dtype=np.float64) for u in inputs]
    nbs = [len(a) for a in nums]
    nas = [len(b) - 1 for b in dens]
    if not 0.0 < radius <= 1.0:
        raise ValueError(f"pole radius must be within (0, 1], got {radius!r}")
    seg = segments if segments is not None else Segments.single(y.size)
    if seg.total != y.size:
        raise ValueError(f"segments cover {seg.total} samples, the record has {y.size}")
    prob = _Problem(y, us, nbs, nas, seg, radius)
    x0: list[float] = []
    lo: list[float] = []
    hi: list[float] = []
    lim = 1.0 - KAPPA_MARGIN
    for a, b in zip(nums, dens, strict=True):
        x0 += [float(v) for v in a]
        lo += [-np.inf] * len(a)
        hi += [np.inf] * len(a)
        x0 += [float(np.clip(k, -lim + 1e-9, lim - 1e-9)) for k in to_kappa(b, radius)]
        lo += [-lim] * (len(b) - 1)
        hi += [lim] * (len(b) - 1)
    start = np.asarray(x0)
    start_cost = float(np.sum(prob.residual(start) ** 2))
    res = least_squares(prob.residual, start, jac=prob.jacobian, bounds=(lo, hi),
                        method="trf", x_scale="jac", max_nfev=max_nfev,
                        xtol=tol, ftol=tol, gtol=tol)
    theta = res.x if float(np.sum(res.fun ** 2)) <= start_cost else start
    parts = prob.unpack(theta)
    out_nums = tuple(tuple(float(v) for v in num) for num, _, _ in parts)
    out_dens = tuple(tuple(float(v) for v in den) for _, _, den in parts)
    return OeEstimate(out_nums, out_dens, fit_pct(y, prob.simulate(theta)), int(res.nfev))
