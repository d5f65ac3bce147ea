"""End to end through the real simulated controllers: a ball-screw axis whose
controller applies the temperature-compensation line a client wrote
(`drivers.sim.ballscrew_machine`). Without compensation the error grows
along the travel; a position-independent value leaves the slope's part;
value and slope written as the controller's parameters leave only the
parameters' encoding (TwinCAT's whole µm/m, SINUMERIK's float32)."""

from __future__ import annotations

from typing import Any

import pytest

from drivers.factory import open_driver
from drivers.sim.ballscrew import constant_program
from drivers.sim.ballscrew_machine import BallscrewMachine
from drivers.sim.registry import make_sim_controller
from drivers.temp_comp import AxisCompensation, write_compensation
from tests.drivers.test_temp_comp import axis_outputs

PROTOCOLS = ("opcua", "s7", "modbus")
#: the controller's encoding of the line: TwinCAT's coefficient is a whole µm/m (at
#: most 0.5 µm/m off: 0.4 µm at 800 mm from the reference) and its offset 0.1 µm
ENCODING_UM = {"opcua": 1e-3, "s7": 1e-3, "modbus": 0.5 * 0.8 + 0.05 + 1e-6}


def _spread(errors: dict[float, float]) -> float:
    return max(errors.values()) - min(errors.values())


@pytest.mark.parametrize("protocol", PROTOCOLS)
async def test_the_controller_applies_value_and_slope_along_the_travel(protocol: str) -> None:
    sim: Any = make_sim_controller(protocol)
    await sim.start()
    outs = axis_outputs(sim.temp_comp, ("x",))
    driver = open_driver(protocol, sim.endpoint, {}, outs.outputs(), timeout_s=2.0)
    # four hours of heavy axis duty: the screw lengthens from its fixed bearing
    machine = BallscrewMachine(sim, hours=4.0, period_s=600.0,
                               program=constant_program(6_000.0, 0.8, 15_000.0))
    try:
        for _ in range(machine.rows - 1):
            none = await machine.tick()
        assert machine.slope_um_m > 30.0  # well beyond the encoding
        growth = {x: machine.growth_um(x) for x in machine.positions_mm}
        assert none == pytest.approx(growth, abs=1e-12)

        # a Z-style offset: one value, the growth at mid-travel, no slope
        mid = machine.growth_um(400.0)
        await write_compensation(driver, outs, {"x": AxisCompensation(mid, 0.0, 0.0)})
        offset_only = await machine.measure()
        assert abs(offset_only[400.0]) < ENCODING_UM[protocol] + 0.05
        assert _spread(offset_only) == pytest.approx(_spread(none), rel=1e-3)

        # the line: value at the fixed bearing and the slope, as the controller takes them
        line = AxisCompensation(machine.value_um, machine.slope_um_m, machine.x0_mm)
        await write_compensation(driver, outs, {"x": line})
        both = await machine.measure()
    finally:
        await driver.close()
        await sim.stop()
    assert max(abs(e) for e in both.values()) <= ENCODING_UM[protocol]
    # the position-dependent part (spread along the travel) is removed
    assert _spread(both) < 0.05 * _spread(offset_only)


async def test_the_record_ends() -> None:
    sim: Any = make_sim_controller("modbus")
    machine = BallscrewMachine(sim, hours=0.5, period_s=900.0)
    assert machine.rows == 3
    await sim.start()
    try:
        await machine.tick()
        await machine.tick()
        with pytest.raises(RuntimeError, match="ends at 1800 s"):
            await machine.tick()
    finally:
        await sim.stop()
    assert set(machine.temperatures()) == {"nut", "screw_bearing", "column", "ambient"}
