"""Value and slope of a position-dependent error, fitted from displacements
measured at several positions along an axis.

A controller's temperature compensation takes per axis a line: a value at a
reference position x0 and a slope (µm/m), e(x) = value + slope · (x - x0) /
1000. A calibration record measures the error at p ≥ 2 positions each row;
per row the p readings are regressed onto that line (ordinary least squares
in x, the same matrix for every row: one solve), then one ARX model is
fitted for the value and one for the slope, each from its own temperatures,
by the same least squares with order selection as `compd fit`'s ARX
baseline (`models.identify.arx.select_arx`). Temperatures enter relative to
the record's first row (the record starts at rest, as the models' zero).

Worked example: positions (0, 500, 1000) mm, x0 = 0, readings (2, 7, 12) µm
give value 2 µm and slope 10 µm/m.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from models.identify.arx import ArxEstimate, select_arx, simulate_common

FloatArray = npt.NDArray[np.float64]

#: the ARX orders tried for each of the value and the slope (denominator, numerators)
DEFAULT_ORDERS: tuple[int, int] = (1, 3)


def line_per_sample(positions_mm: Sequence[float], displacements_um: FloatArray,
                    x0_mm: float = 0.0) -> tuple[FloatArray, FloatArray]:
    """(value at x0 in µm, slope in µm/m) per row of `displacements_um` (rows ×
    positions), the least-squares line through each row's readings. ValueError
    with fewer than two distinct positions, or a shape that does not match."""
    x = np.asarray(positions_mm, dtype=np.float64)
    d = np.asarray(displacements_um, dtype=np.float64)
    if d.ndim != 2 or d.shape[1] != x.size:
        raise ValueError(f"displacements must be rows x {x.size} positions, got shape {d.shape}")
    if np.unique(x).size < 2:
        raise ValueError(f"a line needs displacements at two or more distinct positions, "
                         f"got {x.tolist()} mm")
    design = np.column_stack([np.ones_like(x), (x - x0_mm) / 1000.0])
    coef, *_ = np.linalg.lstsq(design, d.T, rcond=None)
    return coef[0], coef[1]


@dataclass(frozen=True)
class ValueSlopeFit:
    """Two ARX models: the value at `x0_mm` (µm) from `value_inputs`, the slope
    (µm/m) from `slope_inputs`; inputs are rises over the record's first row."""

    x0_mm: float
    value_inputs: tuple[str, ...]
    slope_inputs: tuple[str, ...]
    value: ArxEstimate
    slope: ArxEstimate


def _relative(columns: dict[str, FloatArray], names: Sequence[str]) -> list[FloatArray]:
    missing = [n for n in names if n not in columns]
    if missing:
        raise ValueError(f"no column(s) {missing}; have {sorted(columns)}")
    return [np.asarray(columns[n], dtype=np.float64) - float(columns[n][0]) for n in names]


def fit_line_model(y: FloatArray, columns: dict[str, FloatArray], inputs: Sequence[str],
                   orders: tuple[int, int] = DEFAULT_ORDERS) -> ArxEstimate:
    """One ARX model of `y` from the named temperature columns (relative), the
    orders chosen on a held-out tail as `compd fit` chooses its ARX baseline."""
    if not inputs:
        raise ValueError("a model needs at least one input")
    chosen, _ = select_arx(np.asarray(y, dtype=np.float64), _relative(columns, inputs),
                           orders, orders)
    return chosen


def fit_value_slope(positions_mm: Sequence[float], displacements_um: FloatArray,
                    columns: dict[str, FloatArray], *, value_inputs: Sequence[str],
                    slope_inputs: Sequence[str], x0_mm: float = 0.0,
                    orders: tuple[int, int] = DEFAULT_ORDERS) -> ValueSlopeFit:
    """Regress each row onto a line (`line_per_sample`), then fit the value and
    the slope series each from its own temperatures (`fit_line_model`)."""
    _relative(columns, [*value_inputs, *slope_inputs])  # every input named before fitting
    value, slope = line_per_sample(positions_mm, displacements_um, x0_mm)
    return ValueSlopeFit(x0_mm, tuple(value_inputs), tuple(slope_inputs),
                         fit_line_model(value, columns, value_inputs, orders),
                         fit_line_model(slope, columns, slope_inputs, orders))


def predict_line_model(model: ArxEstimate, columns: dict[str, FloatArray],
                       inputs: Sequence[str]) -> FloatArray:
    """A model's prediction over a record, simulated from rest at its first row."""
    return simulate_common(model.den, model.nums, _relative(columns, inputs))


def predict_at(fit: ValueSlopeFit, columns: dict[str, FloatArray],
               positions_mm: Sequence[float]) -> FloatArray:
    """The predicted error (µm, rows × positions) at each position over a record."""
    value = predict_line_model(fit.value, columns, fit.value_inputs)
    slope = predict_line_model(fit.slope, columns, fit.slope_inputs)
    dx = (np.asarray(positions_mm, dtype=np.float64) - fit.x0_mm) / 1000.0
    return value[:, None] + slope[:, None] * dx[None, :]
