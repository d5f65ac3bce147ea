"""What one per-axis output is built with and what it reports (pure values).

`AxisParams` is one ``[output.axes.<axis>]`` as the cycle is built with it;
`AxisRow` and `ParamRow` are that axis's part of the cycle's report
(`compd.core.plan.Row.axes`). The cycle's work on them is `compd.core.axes`.
The rows are made every cycle for every axis, so they are named tuples (as
`compd.core.plan.Row` is): as immutable as a frozen dataclass, and built
several times faster.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import NamedTuple

from compd.core.faults import FaultState
from compd.core.health import Cause
from models.compensation import CompensationModel

__all__ = ["AXIS_RANGE_FACTOR", "FLOAT_TOLERANCE", "AxisParams", "AxisRow", "ParamRow"]

#: an axis model's output beyond this many times its limit is a fault (as the offset's)
AXIS_RANGE_FACTOR = 5.0
#: a float parameter's read-back tolerance (float32 rounding of what was written), in
#: its unit (µm, µm/m, mm)
FLOAT_TOLERANCE = 0.01


@dataclass(frozen=True)
class AxisParams:
    """One axis as the cycle is built with it (from ``[output.axes.<axis>]``)."""

    axis: str
    value_model: CompensationModel
    slope_model: CompensationModel | None
    reference_mm: float
    value_limit_um: float
    slope_limit_um_m: float
    value_slew_um_s: float
    #: without a slope model the slope stays 0; its rate is then immaterial
    slope_slew_um_m_s: float = 1.0
    value_deadband_um: float = 0.0
    slope_deadband_um_m: float = 0.0
    #: the controller's grid for value (µm) and slope (µm/m); 0: a float
    value_quantum_um: float = 0.0
    slope_quantum_um_m: float = 0.0
    reference_quantum_mm: float = 0.0
    #: each model's identity (a sha256 of its description; "" unknown): a model state
    #: saved by another model is not imported (the model starts at the steady state)
    value_sha256: str = ""
    slope_sha256: str = ""
    #: the channel holding the axis's present position (mm): set, the axis writes one
    #: offset evaluated there (``<axis>_comp_offset``) instead of its three parameters
    position: str | None = None
    #: |offset| written at a position ≤ this (µm; the value's and the slope's limits
    #: over the position channel's range), with the offset address's grid (0: a float)
    offset_limit_um: float = 0.0
    offset_quantum_um: float = 0.0
    #: a value alone is written (the tool direction), no slope or reference
    value_only: bool = False

    def name(self, parameter: str) -> str:
        """The driver output of one of this axis's parameters (`drivers.temp_comp`)."""
        return f"{self.axis}_comp_{parameter}"

    @cached_property
    def names(self) -> tuple[str, ...]:
        """The outputs written (and read back): the offset at the position, or the
        three parameters (worked out once: the cycle asks every cycle)."""
        if self.position is not None:
            return (self.name("offset"),)
        if self.value_only:
            return (self.name("value"),)
        return self.name("value"), self.name("slope"), self.name("reference")

    def offset_at(self, value_um: float, slope_um_m: float, x_mm: float) -> float:
        """The offset written at position `x_mm`: the line there, within
        ±`offset_limit_um`, on the offset address's grid."""
        y = value_um + slope_um_m * (x_mm - self.reference_mm) / 1000.0
        y = max(-self.offset_limit_um, min(self.offset_limit_um, y))
        q = self.offset_quantum_um
        if q > 0.0:
            y = round(y / q) * q
            if abs(y) > self.offset_limit_um:  # the nearest count inside the limit
                y -= math.copysign(q, y)
        return y


class ParamRow(NamedTuple):
    """One parameter of an axis after the cycle: the model's output, the stage's
    value, what was sent (None: nothing) and what the controller last confirmed
    (None: unknown), in µm (value) or µm/m (slope)."""

    model: float | None
    stage: float
    sent: float | None
    confirmed: float | None


class AxisRow(NamedTuple):
    """One axis's part of the cycle's report (`compd.core.plan.Row.axes`)."""

    axis: str
    state: FaultState
    cause: Cause
    status: int
    value: ParamRow
    slope: ParamRow
    reference_mm: float
    #: the axis's line compd wants is the line in force (confirmed this cycle)
    in_force: bool
    #: every input the axis's models read valid and the models stepped
    inputs_valid: bool
    #: an axis written as an offset at its position: the position the offset was
    #: evaluated at (the last valid one, mm) and the offset sent (µm); None otherwise
    position_mm: float | None = None
    offset_um: float | None = None
