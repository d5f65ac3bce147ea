"""The simulated controllers' temperature-compensation parameters, per axis.

Every simulated controller holds, for axes X, Y and Z, the three parameters
of `drivers.temp_comp` in its own memory, in the controller's own units, and
applies them as the controller does: at axis position x (mm) the axis moves
by value + slope·(x - reference)/1000 µm (`AxisCompensation.at`).

- OPC UA and S7 play a SINUMERIK: SD43900 ``$SA_TEMP_COMP_ABS_VALUE`` in mm,
  SD43910 ``$SA_TEMP_COMP_SLOPE`` as tan β, SD43920
  ``$SA_TEMP_COMP_REF_POSITION`` in mm; as OPC UA nodes (Double) or, for S7,
  one data block per axis (three REALs) that the PLC hands on to the NCK.
- Modbus plays a TwinCAT CNC: P-AXIS-00272 position and P-AXIS-00273 offset in
  0.1 µm, P-AXIS-00274 coefficient in µm/m, each a signed 32-bit integer.

The scales below turn those units into compd's (µm, µm/m, mm: engineering
value = raw · scale), so a config's addresses carry the same scales.

A restart of a simulated controller (`forget_outputs`) puts every parameter
back at 0, as a controller whose PLC has not written them yet since power-on.
"""

from __future__ import annotations

from collections.abc import Mapping

from drivers.temp_comp import AXES, PARAMETERS, AxisCompensation, output_name

#: SINUMERIK units -> compd's: mm -> µm, tan β -> µm/m, mm -> mm
SINUMERIK_SCALES: dict[str, float] = {"value": 1000.0, "slope": 1e6, "reference": 1.0}
#: TwinCAT units -> compd's: 0.1 µm -> µm, µm/m -> µm/m, 0.1 µm -> mm
TWINCAT_SCALES: dict[str, float] = {"value": 0.1, "slope": 1.0, "reference": 1e-4}
#: the SINUMERIK setting data's names (the OPC UA sim's node names)
SINUMERIK_DATA: dict[str, str] = {"value": "$SA_TEMP_COMP_ABS_VALUE",
                                  "slope": "$SA_TEMP_COMP_SLOPE",
                                  "reference": "$SA_TEMP_COMP_REF_POSITION"}

#: the channel's tool temperature compensation (SD42960, mm), applied along the tool's
#: orientation (MD20390 $MC_TOOL_TEMP_COMP_ON): the OPC UA sim's node, the S7 sim's DB
TOOL_DATA = "$SC_TOOL_TEMP_COMP"

#: every parameter's output name, per axis
NAMES: tuple[str, ...] = tuple(output_name(axis, p) for axis in AXES for p in PARAMETERS)


def line_of(values: Mapping[str, float], axis: str) -> AxisCompensation:
    """The line a controller holds for `axis`, from its parameters' engineering
    values keyed by output name (`output_name`)."""
    return AxisCompensation(*(float(values[output_name(axis, p)]) for p in PARAMETERS))


__all__ = ["NAMES", "SINUMERIK_DATA", "SINUMERIK_SCALES", "TOOL_DATA", "TWINCAT_SCALES", "line_of"]
