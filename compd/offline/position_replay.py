"""A value model and a slope model replayed over a record with the displacement
measured at several positions (`compd replay VALUE DATA --slope-model SLOPE`).

The correction at position x is the line the controller applies,

    c(x) = value + slope · (x - x0) / 1000        (µm; slope in µm/m)

with each of value and slope stepped by its own model over the record
(`compd.offline.model_replay`, from the starting state the user names). The
error at x before compensation is the measured displacement there, after it
the measured displacement less c(x). Scored per position and over every
position (MAE and RMS, µm), and the position-dependent part: each row's
residues less their mean over the positions (what a position-independent
offset cannot remove, what the slope is for).

The two models say what they are: `compd fit --positions` writes
``positions_column`` (value_um or slope_um_m) and ``reference_position_mm``
into each one's provenance (`check_line_models`); a swapped pair, two
reference positions, or a reference position that differs from the one asked
is refused.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from compd.offline.position_record import SLOPE_COLUMN, VALUE_COLUMN
from compd.offline.records import FloatArray, RecordError

if TYPE_CHECKING:
    from compd.offline.position_record import PositionRecord
    from models.compensation import CompensationModel


class LineModelError(RecordError):
    """The value and slope models do not belong together (one line)."""


def check_line_models(value: CompensationModel, slope: CompensationModel,
                      asked_x0_mm: float | None, *,
                      names: tuple[str, str] = ("", "")) -> tuple[float, str]:
    """The reference position of the pair and where it comes from ("models",
    "asked", "default"); LineModelError when a model was fitted for the other
    half of the line or the reference positions disagree. `names`: the two
    models as the messages name them (their files; default: their names)."""
    x0s: dict[str, float] = {}
    for role, want, model, name in (("value", VALUE_COLUMN, value, names[0]),
                                    ("slope", SLOPE_COLUMN, slope, names[1])):
        shown = name or model.name
        prov: dict[str, Any] = model.provenance
        column = prov.get("positions_column")
        if column is not None and column != want:
            raise LineModelError(f"the {role} model {shown} was fitted on {column!r}, "
                                 f"not {want!r} (compd fit --positions --column {want})")
        x0 = prov.get("reference_position_mm")
        if x0 is not None:
            if not isinstance(x0, int | float) or not math.isfinite(x0):
                raise LineModelError(f"the {role} model {shown}: "
                                     f"reference_position_mm = {x0!r} is not a position")
            x0s[role] = float(x0)
    if len(set(x0s.values())) > 1:
        raise LineModelError(f"the value model's reference position is {x0s['value']:g} mm, "
                             f"the slope model's {x0s['slope']:g} mm: a line has one")
    if x0s:
        x0 = next(iter(x0s.values()))
        if asked_x0_mm is not None and not math.isclose(asked_x0_mm, x0, abs_tol=1e-9):
            raise LineModelError(f"--reference-position-mm {asked_x0_mm:g}: the models were "
                                 f"fitted with the value at {x0:g} mm")
        return x0, "models"
    return (asked_x0_mm, "asked") if asked_x0_mm is not None else (0.0, "default")


@dataclass(frozen=True)
class Figures:
    """MAE and RMS of an error (µm)."""

    mae_um: float
    rms_um: float

    @staticmethod
    def of(error: FloatArray) -> Figures:
        return Figures(float(np.mean(np.abs(error))), float(np.sqrt(np.mean(error ** 2))))


@dataclass(frozen=True)
class PositionScore:
    """Before and after compensation, at each position and over all of them."""

    positions_mm: tuple[float, ...]
    before: tuple[Figures, ...]
    after: tuple[Figures, ...]
    overall_before: Figures
    overall_after: Figures
    #: RMS of the position-dependent part (each row less its mean over the positions)
    dependent_before_rms_um: float
    dependent_after_rms_um: float
    scored_samples: int

    def as_dict(self) -> dict[str, Any]:
        return {
            "positions": [{"position_mm": x, "before_mae_um": b.mae_um,
                           "before_rms_um": b.rms_um, "after_mae_um": a.mae_um,
                           "after_rms_um": a.rms_um}
                          for x, b, a in zip(self.positions_mm, self.before, self.after,
                                             strict=True)],
            "before_mae_um": self.overall_before.mae_um,
            "before_rms_um": self.overall_before.rms_um,
            "after_mae_um": self.overall_after.mae_um,
            "after_rms_um": self.overall_after.rms_um,
            "dependent_before_rms_um": self.dependent_before_rms_um,
            "dependent_after_rms_um": self.dependent_after_rms_um,
            "scored_samples": self.scored_samples,
        }


def correction(value_um: FloatArray, slope_um_m: FloatArray, positions_mm: tuple[float, ...],
               x0_mm: float) -> FloatArray:
    """The line's correction (µm) at each position, rows × positions."""
    dx = (np.asarray(positions_mm, dtype=np.float64) - x0_mm) / 1000.0
    return np.asarray(value_um[:, None] + slope_um_m[:, None] * dx[None, :], dtype=np.float64)


def _dependent_rms(r: FloatArray) -> float:
    return float(np.sqrt(np.mean((r - r.mean(axis=1, keepdims=True)) ** 2)))


def score(pr: PositionRecord, value_um: FloatArray, slope_um_m: FloatArray, x0_mm: float,
          rows: slice) -> PositionScore:
    """The figures over `rows` of the record; RecordError when a prediction is not
    finite there (the models' coefficients do not fit this record)."""
    measured = pr.displacements()[rows]
    corr = correction(value_um, slope_um_m, pr.positions_mm, x0_mm)[rows]
    bad = np.flatnonzero(~np.isfinite(corr).all(axis=1))
    if bad.size:
        raise RecordError(f"{pr.record.path}: the models' output is not finite from scored "
                          f"row {int(bad[0]) + 1} on: their coefficients do not fit this record")
    after = measured - corr
    return PositionScore(
        pr.positions_mm,
        tuple(Figures.of(measured[:, j]) for j in range(measured.shape[1])),
        tuple(Figures.of(after[:, j]) for j in range(after.shape[1])),
        Figures.of(measured), Figures.of(after),
        _dependent_rms(measured), _dependent_rms(after), measured.shape[0])
