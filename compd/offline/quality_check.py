"""Figures of a replay or fit that cannot be reported: say why (exit 65).

A flat displacement column makes fit % 0/0, a model whose output overflows
makes every figure NaN; printing "fit nan %" with exit 0 would pass a
meaningless model. `checked_quality` raises `RecordError` naming the reason.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from compd.offline.records import RecordError
from models.quality import CompensationFigures, quality


def checked_quality(measured: npt.NDArray[np.float64], simulated: npt.NDArray[np.float64],
                    where: str, output: str) -> CompensationFigures:
    """`models.quality.quality`, or why its figures would not mean anything."""
    bad = np.flatnonzero(~np.isfinite(simulated))
    if bad.size:
        raise RecordError(f"{where}: the model's output is not finite from row "
                          f"{int(bad[0]) + 2} on ({bad.size} sample(s)): its coefficients do "
                          "not fit this record")
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        q = quality(measured, simulated)
    if not math.isfinite(q.fit_percent):
        raise RecordError(f"{where}: column {output!r} does not vary about its mean, so fit % "
                          "is undefined (0/0); replay a record where the displacement moves")
    for name in ("residue_min_um", "residue_max_um", "dpk_um"):
        if not math.isfinite(getattr(q, name)):
            raise RecordError(f"{where}: {name} is not finite; the record's values overflow")
    return q
