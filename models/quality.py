"""Quality figures of a compensation (MODELS.md §6).

- residue(k) = measured(k) - simulated(k): what stays after compensation
- fit % = (1 - ‖meas - sim‖ / ‖meas - mean(meas)‖) · 100
- Δpk = |max(residue)| + |min(residue)|
- range reduction = range(meas) / range(residue) (the papers' "n-fold")
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


def _arrays(measured: npt.ArrayLike, simulated: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    m = np.asarray(measured, dtype=np.float64)
    s = np.asarray(simulated, dtype=np.float64)
    if m.shape != s.shape or m.ndim != 1 or m.size == 0:
        raise ValueError(f"measured and simulated must be equal-length 1-D records, "
                         f"got {m.shape} and {s.shape}")
    return m, s


def residue(measured: npt.ArrayLike, simulated: npt.ArrayLike) -> FloatArray:
    m, s = _arrays(measured, simulated)
    return m - s


def fit_percent(measured: npt.ArrayLike, simulated: npt.ArrayLike) -> float:
    m, s = _arrays(measured, simulated)
    spread = float(np.linalg.norm(m - m.mean()))
    if spread == 0.0:
        return math.nan
    return (1.0 - float(np.linalg.norm(m - s)) / spread) * 100.0


def delta_pk(measured: npt.ArrayLike, simulated: npt.ArrayLike) -> float:
    r = residue(measured, simulated)
    return abs(float(r.max())) + abs(float(r.min()))


def range_reduction(measured: npt.ArrayLike, simulated: npt.ArrayLike) -> float:
    m, s = _arrays(measured, simulated)
    r = m - s
    r_range = float(r.max() - r.min())
    m_range = float(m.max() - m.min())
    return math.inf if r_range == 0.0 else m_range / r_range


@dataclass(frozen=True, slots=True)
class CompensationFigures:
    """How well a simulated displacement follows the measured one (µm, %):
    not to be confused with `drivers.base.Quality`, a sample's GOOD/BAD flag."""

    fit_percent: float
    residue_min_um: float
    residue_max_um: float
    dpk_um: float
    range_reduction: float

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


def quality(measured: npt.ArrayLike, simulated: npt.ArrayLike) -> CompensationFigures:
    r = residue(measured, simulated)
    return CompensationFigures(
        fit_percent=fit_percent(measured, simulated),
        residue_min_um=float(r.min()),
        residue_max_um=float(r.max()),
        dpk_um=delta_pk(measured, simulated),
        range_reduction=range_reduction(measured, simulated),
    )
