"""MBOTV parameters by bounded least squares (docs/models.md §6).

zss = α·T + β·Tv + δ·Ta, then two first-order lags (k, γ): simulated with
`lfilter`, equal to `models.mbotv.Mbotv.step` from rest.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares
from scipy.signal import lfilter

from models.identify.arx import fit_pct

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class MbotvFit:
    alpha: float
    beta: float
    delta: float
    k: float
    gamma: float
    fit_pct: float


def simulate_mbotv(x: FloatArray, period_s: float, T: FloatArray) -> FloatArray:
    alpha, beta, delta, k, gamma = (float(v) for v in x)
    tv = np.zeros_like(T)
    tv[1:] = np.diff(T) / period_s
    ta = np.zeros_like(T)
    ta[1:] = np.diff(tv) / period_s
    zss = alpha * T + beta * tv + delta * ta
    z = lfilter([1.0 - k], [1.0, -k], zss)
    return np.asarray(lfilter([1.0 - gamma], [1.0, -gamma], z), dtype=np.float64)


def fit_mbotv(y: FloatArray, T: FloatArray, period_s: float, *,
              with_delta: bool = False) -> MbotvFit:
    """k, γ within [0, 0.999999]; α, β (and δ) free."""
    y = np.asarray(y, dtype=np.float64)
    T = np.asarray(T, dtype=np.float64)
    span = float(np.ptp(T)) or 1.0
    k_hi = 1.0 - 1e-6
    x0 = np.array([float(np.ptp(y)) / span, 0.0, 0.0, float(np.exp(-period_s / 1800.0)),
                   float(np.exp(-period_s / 60.0))])
    lo = np.array([-np.inf, -np.inf, -np.inf if with_delta else -1e-300, 0.0, 0.0])
    hi = np.array([np.inf, np.inf, np.inf if with_delta else 1e-300, k_hi, k_hi])
    x0 = np.clip(x0, lo, hi)

    def residual(x: FloatArray) -> FloatArray:
        return np.asarray(y - simulate_mbotv(x, period_s, T))

    res = least_squares(residual, x0, bounds=(lo, hi), x_scale="jac", method="trf",
                        max_nfev=400)
    x = res.x
    return MbotvFit(alpha=float(x[0]), beta=float(x[1]), delta=float(x[2]) if with_delta else 0.0,
                    k=float(x[3]), gamma=float(x[4]),
                    fit_pct=fit_pct(y, simulate_mbotv(x, period_s, T)))
