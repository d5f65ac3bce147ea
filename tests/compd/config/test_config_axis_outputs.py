"""``[output.axes.<axis>]``: the per-axis temperature-compensation outputs of a
config (`compd.config.axis_outputs`), each refusal one ConfigError naming the key."""

from __future__ import annotations

import math
import tomllib
from typing import Any

import pytest

from compd.config.axis_outputs import PositionChannel, parse_axis_outputs
from compd.errors import ConfigError
from drivers.addresses import LinuxCncEoffset, ModbusAddress
from drivers.sim.modbus_server import TEMP_COMP as MODBUS_SIM
from drivers.sim.opcua_server import OpcUaSimController
from drivers.temp_comp import AxisCompensation, CompensationRefused

OPCUA = tomllib.loads('''
[x]
value = { node = "ns=2;s=Machine.X.$SA_TEMP_COMP_ABS_VALUE", scale = 1000.0 }
slope = { node = "ns=2;s=Machine.X.$SA_TEMP_COMP_SLOPE", scale = 1e6 }
reference = { node = "ns=2;s=Machine.X.$SA_TEMP_COMP_REF_POSITION" }
reference_mm = 25.0
value_limit_um = 100.0
slope_limit_um_m = 50.0
''')


def _twincat(axis: str = "x", base: int = 32, **over: Any) -> dict[str, Any]:
    doc: dict[str, Any] = {
        "reference": {"kind": "holding", "address": base, "type": "int32", "scale": 0.0001},
        "value": {"kind": "holding", "address": base + 2, "type": "int32", "scale": 0.1},
        "slope": {"kind": "holding", "address": base + 4, "type": "int32"},
        "value_limit_um": 200.0, "slope_limit_um_m": 40.0}
    doc.update(over)
    return {axis: doc}


def test_the_opcua_example_names_the_sim_nodes() -> None:
    got = parse_axis_outputs("opcua", OPCUA)
    sim = OpcUaSimController()
    assert got.outputs.outputs() == {n: a for n, a in sim.temp_comp.items()
                                     if n.startswith("x_")}
    assert got.reference_mm == {"x": 25.0}
    assert got.line("x", 3.0, -2.0) == AxisCompensation(3.0, -2.0, 25.0)
    # the drivers' refusals carry the config's key
    with pytest.raises(CompensationRefused, match=r"^output\.axes\.x\.slope_um_m: "):
        got.outputs.writes({"x": got.line("x", 3.0, 60.0)})


def test_the_twincat_layout_is_the_modbus_sims() -> None:
    doc = {**_twincat("x", 32), **_twincat("y", 38), **_twincat("z", 44)}
    got = parse_axis_outputs("modbus", doc)
    assert got.outputs.outputs() == MODBUS_SIM
    assert got.outputs.axes == ("x", "y", "z")
    # TwinCAT holds the offset in 0.1 µm and the coefficient in whole µm/m
    assert got.quanta == dict.fromkeys("xyz", (0.1, 1.0))
    assert parse_axis_outputs("opcua", OPCUA).quanta == {"x": (0.0, 0.0)}


@pytest.mark.parametrize(("doc", "key", "reason"), [
    (_twincat("w"), "output.axes.w", "unknown axis"),
    (_twincat(colour="red"), "output.axes.x.colour", "unknown key"),
    (_twincat(value_limit_um=0.0), "output.axes.x.value_limit_um", "must be > 0"),
    (_twincat(slope_limit_um_m=math.nan), "output.axes.x.slope_limit_um_m", "finite"),
    (_twincat(reference_mm=math.inf), "output.axes.x.reference_mm", "finite"),
    (_twincat(slope={"kind": "input", "address": 36, "type": "int32"}),
     "output.axes.x.slope", "read-only"),
    (_twincat(value={"db": 1, "offset": 0}), "output.axes.x.value", "s7 address"),
    # int16 at 0.1 µm holds ±3276.7 µm: a limit of 5 mm does not fit
    (_twincat(value={"address": 34, "type": "int16", "scale": 0.1}, value_limit_um=5000.0),
     "output.axes.x.value", "value_limit_um = 5000 needs"),
    # the slope overlapping the value's second register
    (_twincat(slope={"address": 35, "type": "int32"}), "output.axes.x.", "overlap"),
])
def test_refusals_name_the_key(doc: dict[str, Any], key: str, reason: str) -> None:
    with pytest.raises(ConfigError) as err:
        parse_axis_outputs("modbus", doc)
    assert err.value.key.startswith(key), err.value
    assert reason in err.value.reason, err.value


def test_missing_address_named() -> None:
    doc = _twincat()
    del doc["x"]["slope"]
    with pytest.raises(ConfigError, match=r"^output\.axes\.x\.slope: required key"):
        parse_axis_outputs("modbus", doc)


def test_no_parameter_may_overlap_the_offset() -> None:
    others = {"output.offset": ModbusAddress(address=34, type="float32")}
    with pytest.raises(ConfigError) as err:
        parse_axis_outputs("modbus", _twincat(), others=others)
    assert err.value.key.startswith("output.axes.x.") or err.value.key == "output.offset"
    assert "output.offset" in str(err.value) and "output.axes.x.value" in str(err.value)


def test_linuxcnc_has_no_parameters() -> None:
    with pytest.raises(ConfigError, match=r"^output\.axes\.x: a linuxcnc controller has no"):
        parse_axis_outputs("linuxcnc", {"x": {}})


def _linuxcnc_x(**offset: object) -> dict[str, object]:
    return {"position": "x_pos", "value_limit_um": 50.0, "slope_limit_um_m": 20.0,
            "offset": {"kind": "eoffset", "axis": "x", "counts_net": "compd-x-counts",
                       "enable_net": "compd-x-enable", "scale": 0.1, **offset}}


LINUXCNC_POSITIONS = {"x_pos": PositionChannel((-100.0, 100.0), 5.0)}


def test_linuxcnc_takes_an_axis_at_its_position_as_its_eoffset() -> None:
    z = LinuxCncEoffset(kind="eoffset", axis="z")
    found = parse_axis_outputs("linuxcnc", {"x": _linuxcnc_x()}, others={"output.offset": z},
                               positions=LINUXCNC_POSITIONS)
    offset = found.positional["x"].offset
    assert isinstance(offset, LinuxCncEoffset) and offset.axis == "x"
    assert found.driver_outputs()["x_comp_offset"] is offset
    # the parameter form is refused, naming the axis
    with pytest.raises(ConfigError, match=r"^output\.axes\.x: a linuxcnc controller"):
        parse_axis_outputs("linuxcnc", {"x": {k: v for k, v in _linuxcnc_x().items()
                                              if k != "position"}})
    # another axis's external offset, or not an external offset at all
    with pytest.raises(ConfigError, match=r"^output\.axes\.x\.offset\.axis: must be 'x'"):
        parse_axis_outputs("linuxcnc", {"x": _linuxcnc_x(axis="y")},
                           positions=LINUXCNC_POSITIONS)
    pin = {"position": "x_pos", "value_limit_um": 50.0, "slope_limit_um_m": 20.0,
           "offset": {"pin": "x-off", "net": "compd-x-off"}}
    with pytest.raises(ConfigError, match=r"^output\.axes\.x\.offset: on LinuxCNC"):
        parse_axis_outputs("linuxcnc", {"x": pin}, positions=LINUXCNC_POSITIONS)
    # Z's external offset already written by [output] offset: one writer per axis
    z_axis = {**_linuxcnc_x(axis="z", counts_net="compd-z2-counts",
                            enable_net="compd-z2-enable"), "position": "x_pos"}
    with pytest.raises(ConfigError, match=r"^output\.axes\.z\.offset: axis Z's external "
                                          r"offset is written by output\.offset"):
        parse_axis_outputs("linuxcnc", {"z": z_axis}, others={"output.offset": z},
                           positions=LINUXCNC_POSITIONS)
