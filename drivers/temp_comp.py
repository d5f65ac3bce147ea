"""The controller's own temperature-compensation parameters, per axis.

SINUMERIK (function manual K3) and TwinCAT CNC compensate heat per axis with a
line along the axis, applied by the controller at every position x (mm)::

    compensation(x) = value + slope · (x - reference) / 1000      (µm)

with `value` in µm at the reference position, `slope` in µm/m and `reference`
in mm. The parameters that hold it:

=========  ==========================================  =============================
parameter  SINUMERIK setting data (per axis)           TwinCAT CNC axis parameter
=========  ==========================================  =============================
value      SD43900 ``$SA_TEMP_COMP_ABS_VALUE`` (mm)    P-AXIS-00273 offset (0.1 µm)
slope      SD43910 ``$SA_TEMP_COMP_SLOPE`` (tan β)     P-AXIS-00274 coefficient (µm/m)
reference  SD43920 ``$SA_TEMP_COMP_REF_POSITION`` (mm) P-AXIS-00272 position (0.1 µm)
=========  ==========================================  =============================

compd speaks µm, µm/m and mm; each address's ``scale`` turns the controller's
own unit into them (engineering value = raw · scale, as for every address):
a SINUMERIK value in mm has scale 1000, a slope as tan β scale 1e6; a TwinCAT
offset in 0.1 µm scale 0.1, its position scale 0.0001.

This module is the typed face of those outputs over the one driver interface
(`drivers.base.Driver`): `AxisOutputs` names each axis's three parameters as
driver outputs (``x_comp_value``, ``x_comp_slope``, ``x_comp_reference``),
turns an `AxisCompensation` per axis into the values `Driver.write` takes (so
they go out in the same request as the offset, heartbeat and status where the
protocol allows) and read-back samples into the values the controller
confirms. The encoding, the address checks and the write path are the
drivers' own; here are only the refusals that come before any I/O: a
non-finite number, a value or slope outside the axis's limits, an axis that
is not configured (`CompensationRefused`, naming the key).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal, get_args

from drivers.addresses import Address
from drivers.base import Driver, Quality, Sample
from drivers.errors import DriverError

#: the axes whose compensation line a controller takes
Axis = Literal["x", "y", "z"]
AXES: tuple[str, ...] = get_args(Axis)
#: one axis's parameters, in the order they are written
Parameter = Literal["value", "slope", "reference"]
PARAMETERS: tuple[str, ...] = get_args(Parameter)
#: the unit compd speaks for each parameter (the address's scale converts)
UNITS: dict[str, str] = {"value": "µm", "slope": "µm/m", "reference": "mm"}

#: the controllers' names of the parameters (docs, messages)
SINUMERIK_NAMES: dict[str, str] = {
    "value": "SD43900 $SA_TEMP_COMP_ABS_VALUE",
    "slope": "SD43910 $SA_TEMP_COMP_SLOPE",
    "reference": "SD43920 $SA_TEMP_COMP_REF_POSITION"}
TWINCAT_NAMES: dict[str, str] = {
    "value": "P-AXIS-00273 temp_comp_offset_0",
    "slope": "P-AXIS-00274 temp_comp_coefficient",
    "reference": "P-AXIS-00272 temp_comp_position_0"}


def output_name(axis: str, parameter: str) -> str:
    """The driver output of one axis's parameter: ``x_comp_value``, ``z_comp_slope``."""
    return f"{axis}_comp_{parameter}"


class CompensationRefused(DriverError, ValueError):
    """We refused to send a compensation line (nothing was written). `key` is
    the dotted key of what was refused (``axes.x.slope_um_m``)."""

    def __init__(self, key: str, reason: str, *, channel: str | None = None) -> None:
        self.key = key
        self.reason = reason
        super().__init__(f"{key}: {reason}", channel=channel)


@dataclass(frozen=True, slots=True)
class AxisCompensation:
    """One axis's line: `value_um` at `reference_mm`, rising `slope_um_m` per metre."""

    value_um: float
    slope_um_m: float
    reference_mm: float = 0.0

    def at(self, x_mm: float) -> float:
        """The compensation at axis position `x_mm`, µm.

        Worked number: value 10 µm, slope 11.5 µm/m, reference 0 mm: at 400 mm
        10 + 11.5 · 0.4 = 14.6 µm."""
        return self.value_um + self.slope_um_m * (x_mm - self.reference_mm) / 1000.0


@dataclass(frozen=True, slots=True)
class AxisLimits:
    """What compd may send for one axis: |value| ≤ `value_limit_um`,
    |slope| ≤ `slope_limit_um_m` (a controller limits the slope too: SINUMERIK's
    MD32760 bounds tan β)."""

    value_limit_um: float
    slope_limit_um_m: float

    def __post_init__(self) -> None:
        for name in ("value_limit_um", "slope_limit_um_m"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0.0):
                raise ValueError(f"{name} must be a finite number > 0, got {v!r}")


@dataclass(frozen=True, slots=True)
class AxisAddresses:
    """Where one axis's three parameters live on the controller."""

    value: Address
    slope: Address
    reference: Address

    def by_parameter(self) -> dict[str, Address]:
        return {"value": self.value, "slope": self.slope, "reference": self.reference}


def _finite(key: str, v: float, channel: str) -> float:
    if not isinstance(v, int | float) or isinstance(v, bool) or not math.isfinite(v):
        raise CompensationRefused(key, f"{v!r} is not a finite number", channel=channel)
    return float(v)


@dataclass(frozen=True)
class AxisOutputs:
    """The per-axis compensation outputs of one controller (see the module).

    `key` prefixes the keys refusals name (the config's table, ``output.axes``)."""

    addresses: Mapping[str, AxisAddresses]
    limits: Mapping[str, AxisLimits]
    key: str = "axes"

    def __post_init__(self) -> None:
        for axis in self.addresses:
            if axis not in AXES:
                raise CompensationRefused(f"{self.key}.{axis}",
                                          f"unknown axis; known: {', '.join(AXES)}")
        missing = sorted(set(self.addresses) ^ set(self.limits))
        if missing:
            raise CompensationRefused(f"{self.key}.{missing[0]}",
                                      "an axis needs both its addresses and its limits")

    @property
    def axes(self) -> tuple[str, ...]:
        """The configured axes, in X, Y, Z order."""
        return tuple(a for a in AXES if a in self.addresses)

    def outputs(self) -> dict[str, Address]:
        """Output name -> address, for the driver's outputs table."""
        return {output_name(axis, p): addr for axis in self.axes
                for p, addr in self.addresses[axis].by_parameter().items()}

    def names(self, axes: tuple[str, ...] | None = None) -> list[str]:
        """The output names of `axes` (all configured ones by default), to read back."""
        return [output_name(axis, p) for axis in self._known(axes or self.axes)
                for p in PARAMETERS]

    def _known(self, axes: tuple[str, ...]) -> tuple[str, ...]:
        for axis in axes:
            if axis not in self.addresses:
                known = ", ".join(self.axes) or "none"
                raise CompensationRefused(f"{self.key}.{axis}",
                                          f"not a configured axis (configured: {known})")
        return axes

    def writes(self, lines: Mapping[str, AxisCompensation]) -> dict[str, float]:
        """The driver writes for `lines` (axis -> line); `CompensationRefused`, with
        nothing written, for an unknown axis, a non-finite number or a value or
        slope beyond the axis's limits."""
        out: dict[str, float] = {}
        for axis in self._known(tuple(lines)):
            line, lim, key = lines[axis], self.limits[axis], f"{self.key}.{axis}"
            value = _finite(f"{key}.value_um", line.value_um, output_name(axis, "value"))
            slope = _finite(f"{key}.slope_um_m", line.slope_um_m, output_name(axis, "slope"))
            ref = _finite(f"{key}.reference_mm", line.reference_mm,
                          output_name(axis, "reference"))
            if abs(value) > lim.value_limit_um:
                raise CompensationRefused(
                    f"{key}.value_um", f"{value:g} µm is beyond ±{lim.value_limit_um:g} µm "
                    "(value_limit_um)", channel=output_name(axis, "value"))
            if abs(slope) > lim.slope_limit_um_m:
                raise CompensationRefused(
                    f"{key}.slope_um_m", f"{slope:g} µm/m is beyond "
                    f"±{lim.slope_limit_um_m:g} µm/m (slope_limit_um_m)",
                    channel=output_name(axis, "slope"))
            out[output_name(axis, "value")] = value
            out[output_name(axis, "slope")] = slope
            out[output_name(axis, "reference")] = ref
        return out

    def confirmed(self, samples: Mapping[str, Sample]) -> dict[str, AxisCompensation | None]:
        """The line each configured axis's controller holds, from read-back
        samples: None for an axis with a parameter missing, of BAD quality or
        not finite (nothing is confirmed then)."""
        out: dict[str, AxisCompensation | None] = {}
        for axis in self.axes:
            got: list[float] = []
            for p in PARAMETERS:
                s = samples.get(output_name(axis, p))
                if s is None or s.quality is Quality.BAD or not math.isfinite(s.value):
                    break
                got.append(s.value)
            out[axis] = AxisCompensation(*got) if len(got) == len(PARAMETERS) else None
        return out


async def write_compensation(driver: Driver, outputs: AxisOutputs,
                             lines: Mapping[str, AxisCompensation],
                             also: Mapping[str, float] | None = None) -> None:
    """Write `lines` (checked first: `AxisOutputs.writes`) and `also` (the
    heartbeat, the status word, the offset) in one `Driver.write`."""
    values = outputs.writes(lines)
    if also:
        values = {**also, **values}
    await driver.write(values)


async def read_compensation(driver: Driver, outputs: AxisOutputs,
                            axes: tuple[str, ...] | None = None
                            ) -> dict[str, AxisCompensation | None]:
    """The lines the controller holds now for `axes` (all configured ones by
    default), in one `Driver.read`."""
    samples = await driver.read(outputs.names(axes))
    confirmed = outputs.confirmed(samples)
    return {axis: confirmed[axis] for axis in (axes or outputs.axes)}


__all__ = ["AXES", "PARAMETERS", "SINUMERIK_NAMES", "TWINCAT_NAMES", "UNITS", "Axis",
           "AxisAddresses", "AxisCompensation", "AxisLimits", "AxisOutputs",
           "CompensationRefused", "Parameter", "output_name", "read_compensation",
           "write_compensation"]
