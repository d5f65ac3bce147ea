"""Grey-box ODE parameters by bounded least squares (docs/models.md §5).

The Euler step y(k) = (1 + Ts·p1)·y(k-1) + Ts·p2·(u1(k) + p3) is a first-order
filter between switchings of u2, so a whole record is simulated with a few
`lfilter` calls (one per run of constant u2) carrying the state across; the
result equals `models.greybox.GreyBox.step` sample by sample.
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
class GreyBoxFit:
    p: tuple[float, ...]
    fit_pct: float


def simulate_greybox(p: FloatArray, period_s: float, u1: FloatArray,
                     u2: FloatArray | None = None) -> FloatArray:
    n = u1.size
    y = np.empty(n)
    moving = np.ones(n, dtype=bool) if u2 is None else (u2 >= 0.5)
    edges = np.flatnonzero(np.diff(moving.astype(np.int8))) + 1
    starts = np.concatenate(([0], edges))
    ends = np.concatenate((edges, [n]))
    prev = 0.0
    for s, e in zip(starts.tolist(), ends.tolist(), strict=True):
        rate, gain, bias = (p[0], p[1], p[2]) if moving[s] or p.size == 3 else (p[3], p[4], p[5])
        pole = 1.0 + period_s * rate
        seg, _ = lfilter([period_s * gain], [1.0, -pole], u1[s:e] + bias, zi=[pole * prev])
        y[s:e] = seg
        prev = float(seg[-1])
    return y


def fit_greybox(y: FloatArray, u1: FloatArray, period_s: float,
                u2: FloatArray | None = None) -> GreyBoxFit:
    """Fit p1..p3 (or p1..p6 with the switch u2); time constants between two
    samples and 100 days, p1, p4 < 0 so that the Euler step settles."""
    y = np.asarray(y, dtype=np.float64)
    u1 = np.asarray(u1, dtype=np.float64)
    rate_lo, rate_hi = -1.0 / period_s * 0.999, -1.0 / (100 * 86400.0)
    tau0 = 3600.0
    span_u = float(np.ptp(u1)) or 1.0
    gain0 = float(np.ptp(y)) / span_u / tau0
    one = [-1.0 / tau0, gain0, 0.0]
    x0 = np.array(one * (2 if u2 is not None else 1))
    lo = [rate_lo, -np.inf, -np.inf] * (2 if u2 is not None else 1)
    hi = [rate_hi, np.inf, np.inf] * (2 if u2 is not None else 1)

    def residual(p: FloatArray) -> FloatArray:
        return np.asarray(y - simulate_greybox(p, period_s, u1, u2))

    res = least_squares(residual, x0, bounds=(lo, hi), x_scale="jac", method="trf",
                        max_nfev=400)
    p = res.x
    return GreyBoxFit(tuple(float(v) for v in p), fit_pct(y, simulate_greybox(p, period_s, u1, u2)))
