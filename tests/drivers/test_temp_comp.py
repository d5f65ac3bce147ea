"""The per-axis temperature-compensation outputs (`drivers.temp_comp`): the
refusals before any I/O, and the contract against the real simulated
controllers (OPC UA and S7 as a SINUMERIK, Modbus as a TwinCAT CNC) on
127.0.0.1: write then read back per axis, the controller applying the line,
a second client's write seen, a restarted controller's zeros seen."""

from __future__ import annotations

import importlib
import math
from collections.abc import AsyncIterator
from typing import Any

import pytest

from drivers.addresses import ModbusAddress
from drivers.base import Quality, Sample
from drivers.errors import DriverError
from drivers.sim import AXIS_OUTPUTS
from drivers.sim.temp_comp import NAMES
from drivers.temp_comp import (
    AXES,
    AxisAddresses,
    AxisCompensation,
    AxisLimits,
    AxisOutputs,
    CompensationRefused,
    output_name,
    read_compensation,
    write_compensation,
)
from tests.drivers.harness_types import Harness

PROTOCOLS = ("opcua", "s7", "modbus")
LIMITS = AxisLimits(value_limit_um=500.0, slope_limit_um_m=200.0)
#: lines on every controller's grid (TwinCAT: 0.1 µm, whole µm/m, 0.1 µm positions)
LINES = {"x": AxisCompensation(12.3, 11.0, 150.0),
         "y": AxisCompensation(-7.5, 4.0, -20.5),
         "z": AxisCompensation(3.2, -6.0, 0.0)}
#: float32 in mm and tan β (SINUMERIK REALs) round-trips within this, µm and µm/m
TOL = 1e-3


def axis_outputs(table: dict[str, Any], axes: tuple[str, ...] = AXES) -> AxisOutputs:
    return AxisOutputs(
        {a: AxisAddresses(table[output_name(a, "value")], table[output_name(a, "slope")],
                          table[output_name(a, "reference")]) for a in axes},
        dict.fromkeys(axes, LIMITS))


def assert_line(got: AxisCompensation | None, want: AxisCompensation) -> None:
    assert got is not None
    assert math.isclose(got.value_um, want.value_um, abs_tol=TOL), (got, want)
    assert math.isclose(got.slope_um_m, want.slope_um_m, abs_tol=TOL), (got, want)
    assert math.isclose(got.reference_mm, want.reference_mm, abs_tol=TOL), (got, want)


# -- refusals (no I/O) ----------------------------------------------------------------

def _outputs() -> AxisOutputs:
    addr = ModbusAddress(address=32, type="int32")
    return AxisOutputs({"x": AxisAddresses(addr, addr, addr)}, {"x": LIMITS},
                       key="output.axes")


def test_the_line_at_a_position() -> None:
    line = AxisCompensation(value_um=10.0, slope_um_m=11.5, reference_mm=100.0)
    assert line.at(100.0) == 10.0
    assert math.isclose(line.at(500.0), 10.0 + 11.5 * 0.4)
    assert math.isclose(line.at(0.0), 10.0 - 1.15)


def test_writes_name_each_parameter() -> None:
    assert _outputs().writes({"x": AxisCompensation(1.5, -2.0, 30.0)}) == {
        "x_comp_value": 1.5, "x_comp_slope": -2.0, "x_comp_reference": 30.0}


@pytest.mark.parametrize(("line", "key"), [
    (AxisCompensation(math.nan, 0.0), "output.axes.x.value_um"),
    (AxisCompensation(0.0, math.inf), "output.axes.x.slope_um_m"),
    (AxisCompensation(0.0, 0.0, -math.inf), "output.axes.x.reference_mm"),
    (AxisCompensation(500.5, 0.0), "output.axes.x.value_um"),
    (AxisCompensation(-501.0, 0.0), "output.axes.x.value_um"),
    (AxisCompensation(0.0, 200.01), "output.axes.x.slope_um_m"),
    (AxisCompensation(0.0, -250.0), "output.axes.x.slope_um_m"),
])
def test_refusals_name_the_key(line: AxisCompensation, key: str) -> None:
    with pytest.raises(CompensationRefused) as err:
        _outputs().writes({"x": line})
    assert err.value.key == key
    assert str(err.value).startswith(f"{key}: ")
    # a driver error (the cycle's write outcome handles it) and a value error
    assert isinstance(err.value, DriverError) and isinstance(err.value, ValueError)


def test_limits_are_inclusive() -> None:
    assert _outputs().writes({"x": AxisCompensation(-500.0, 200.0)})["x_comp_slope"] == 200.0


@pytest.mark.parametrize("axis", ["y", "w", "X"])
def test_unknown_axis_refused(axis: str) -> None:
    with pytest.raises(CompensationRefused, match=rf"^output\.axes\.{axis}: not a configured"):
        _outputs().writes({axis: AxisCompensation(0.0, 0.0)})
    with pytest.raises(CompensationRefused, match=rf"^output\.axes\.{axis}: "):
        _outputs().names((axis,))


def test_unknown_axis_in_the_addresses_refused() -> None:
    addr = ModbusAddress(address=32, type="int32")
    with pytest.raises(CompensationRefused, match=r"^axes\.a: unknown axis; known: x, y, z"):
        AxisOutputs({"a": AxisAddresses(addr, addr, addr)}, {"a": LIMITS})


@pytest.mark.parametrize("bad", [0.0, -1.0, math.nan, math.inf])
def test_limits_must_be_positive_and_finite(bad: float) -> None:
    with pytest.raises(ValueError, match="value_limit_um"):
        AxisLimits(value_limit_um=bad, slope_limit_um_m=1.0)
    with pytest.raises(ValueError, match="slope_limit_um_m"):
        AxisLimits(value_limit_um=1.0, slope_limit_um_m=bad)


def test_confirmed_needs_all_three_good_values() -> None:
    outs = _outputs()
    good = {n: Sample(v, 0.0) for n, v in
            {"x_comp_value": 1.0, "x_comp_slope": 2.0, "x_comp_reference": 3.0}.items()}
    assert outs.confirmed(good) == {"x": AxisCompensation(1.0, 2.0, 3.0)}
    assert outs.confirmed({**good, "x_comp_slope": Sample(2.0, 0.0, Quality.BAD)}) == {"x": None}
    assert outs.confirmed({**good, "x_comp_value": Sample(math.nan, 0.0)}) == {"x": None}
    del good["x_comp_reference"]
    assert outs.confirmed(good) == {"x": None}


def test_sim_names_are_the_output_names() -> None:
    assert AXIS_OUTPUTS == NAMES


# -- against the simulated controllers ---------------------------------------------------------

@pytest.fixture(params=PROTOCOLS)
async def harness(request: pytest.FixtureRequest) -> AsyncIterator[Harness]:
    module: Any = importlib.import_module(f"tests.drivers.harness_{request.param}")
    async with module.harness() as h:
        yield h


def _driver(h: Harness, outs: AxisOutputs) -> Any:
    # a generous timeout: a busy machine makes these tests slower, never red
    return h.make_driver(timeout_s=2.0, outputs={**h.sim.outputs_map, **outs.outputs()})


async def test_write_and_read_back_every_axis(harness: Harness) -> None:
    sim: Any = harness.sim
    outs = axis_outputs(sim.temp_comp)
    driver = _driver(harness, outs)
    try:
        await write_compensation(driver, outs, LINES, also={"heartbeat": 41, "offset": 2.5})
        confirmed = await read_compensation(driver, outs)
    finally:
        await driver.close()
    for axis, want in LINES.items():
        assert_line(confirmed[axis], want)
        # the controller applies the line it holds: value + slope·(x - ref)/1000
        held = await sim.compensation(axis)
        assert_line(held, want)
        for x_mm in (-100.0, 0.0, 400.0, 800.0):
            assert math.isclose(held.at(x_mm), want.at(x_mm), abs_tol=2 * TOL), (axis, x_mm)
    # the heartbeat and offset went out in the same write, unchanged
    outputs = await sim.outputs()
    assert outputs["heartbeat"] == 41
    assert math.isclose(outputs["offset"], 2.5, abs_tol=harness.tolerance)


async def test_one_axis_leaves_the_others(harness: Harness) -> None:
    sim: Any = harness.sim
    outs = axis_outputs(sim.temp_comp)
    driver = _driver(harness, outs)
    try:
        await write_compensation(driver, outs, LINES)
        await write_compensation(driver, outs, {"y": AxisCompensation(1.0, 2.0, 3.0)})
        confirmed = await read_compensation(driver, outs, ("x", "y"))
    finally:
        await driver.close()
    assert set(confirmed) == {"x", "y"}
    assert_line(confirmed["x"], LINES["x"])
    assert_line(confirmed["y"], AxisCompensation(1.0, 2.0, 3.0))
    assert_line(await sim.compensation("z"), LINES["z"])


async def test_a_refused_line_writes_nothing(harness: Harness) -> None:
    sim: Any = harness.sim
    outs = axis_outputs(sim.temp_comp)
    driver = _driver(harness, outs)
    try:
        await write_compensation(driver, outs, {"x": LINES["x"]})
        with pytest.raises(CompensationRefused, match=r"^axes\.z\.slope_um_m: "):
            await write_compensation(driver, outs, {"x": AxisCompensation(99.0, 0.0),
                                                    "z": AxisCompensation(0.0, 999.0)},
                                     also={"heartbeat": 5})
    finally:
        await driver.close()
    assert_line(await sim.compensation("x"), LINES["x"])
    assert (await sim.outputs())["heartbeat"] == 0


async def test_a_second_client_is_seen_on_read_back(harness: Harness) -> None:
    sim: Any = harness.sim
    outs = axis_outputs(sim.temp_comp)
    ours, other = _driver(harness, outs), _driver(harness, outs)
    try:
        await write_compensation(ours, outs, LINES)
        # someone else (an HMI, another PLC program) overwrites X's slope
        await other.write({"x_comp_slope": -20.0})
        confirmed = await read_compensation(ours, outs)
    finally:
        await ours.close()
        await other.close()
    assert_line(confirmed["x"], AxisCompensation(LINES["x"].value_um, -20.0,
                                                 LINES["x"].reference_mm))
    assert_line(confirmed["z"], LINES["z"])
    assert_line(await sim.compensation("x"), confirmed["x"] or LINES["x"])


async def test_a_restarted_controller_is_seen_at_zero(harness: Harness) -> None:
    sim: Any = harness.sim
    outs = axis_outputs(sim.temp_comp)
    driver = _driver(harness, outs)
    try:
        await write_compensation(driver, outs, LINES)
        await harness.restart()
        confirmed = await _read_when_back(driver, outs)
    finally:
        await driver.close()
    for axis in AXES:
        assert confirmed[axis] == AxisCompensation(0.0, 0.0, 0.0), axis
        assert (await sim.compensation(axis)).at(800.0) == 0.0


async def _read_when_back(driver: Any, outs: AxisOutputs
                          ) -> dict[str, AxisCompensation | None]:
    from tests.drivers.test_contract import _read_when_back as read

    samples = await read(driver, outs.names())
    return outs.confirmed(samples)
