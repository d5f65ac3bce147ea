"""The per-axis line end to end over the real OPC UA and S7 drivers to their
simulated controllers, playing a SINUMERIK (SD43900 value, SD43910 slope,
SD43920 reference position, `drivers.sim.temp_comp`), as
`test_axes_ballscrew` does over Modbus: the controller's own arithmetic
applies the line along the travel (`drivers.sim.ballscrew_machine`), another
client's write to the axis's value is found and ramped from, and a power
cycle of the controller (its parameters back at 0, the link dropped) resumes
at the axis's rate, never a jump. The axes word goes to the controller in the
same write and says which axes are in force."""

from __future__ import annotations

import tomllib
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import pytest

from compd.config.loader import parse_config
from compd.core.cycle import Cycle
from compd.core.events import EventName
from compd.core.health import Cause
from compd.core.output import AxesStatus
from compd.core.params import params_from_config
from compd.runtime.driver_setup import build_driver
from drivers.addresses import S7Address
from drivers.sim.ballscrew import TEMPERATURES
from drivers.sim.ballscrew_machine import BallscrewMachine
from drivers.sim.opcua_server import OpcUaSimController
from drivers.sim.s7_server import S7SimController
from tests.compd.axes_helpers import SENSOR_CHANNELS, axes_config_text, drive_cycle
from tests.compd.runtime.test_axes_ballscrew import HOURS, PERIOD_S, PROGRAM, _slope_gains

#: the value's and slope's rate limits (µm/s, µm/m per s): one cycle moves them this
#: far at most (30 µm, 30 µm/m)
SLEW = 0.05
STEP = SLEW * PERIOD_S

Sim = OpcUaSimController | S7SimController


def _doc(sim: Sim, t0: float, sn: float, sb: float) -> dict[str, Any]:
    """The Modbus axes config of `axes_helpers` with the sim's own addresses."""
    doc = tomllib.loads(axes_config_text(period_s=PERIOD_S, time_scale=1.0, timeout_s=2.0,
                                         t0=t0, sn=sn, sb=sb, value_slew=SLEW,
                                         slope_slew=SLEW))
    doc["controller"] = {**doc["controller"], "protocol": sim.protocol,
                         "endpoint": sim.endpoint}
    if sim.protocol == "opcua":
        doc["controller"]["security"] = {"policy": "None", "insecure": True}
        # a writable integer node of the sim stands for the PLC's axes word
        axes_word = {"node": "ns=2;s=Machine.enc_int64"}
    else:
        axes_word = S7Address(db=2, offset=10, type="WORD").model_dump()
    for name, sensor in SENSOR_CHANNELS.items():
        doc["channels"][name]["address"] = sim.channels[sensor].model_dump()
    out = doc["output"]
    for name in ("offset", "heartbeat", "status"):
        out[name] = sim.outputs_map[name].model_dump()
    out["axes_status"] = axes_word
    for p in ("value", "slope", "reference"):
        out["axes"]["x"][p] = sim.temp_comp[f"x_comp_{p}"].model_dump()
    return doc




async def _opcua_power_cycle(sim: Sim) -> None:
    assert isinstance(sim, OpcUaSimController)
    await sim.restart()  # every connection dropped, every output and parameter at 0


async def _s7_power_cycle(sim: Sim) -> None:
    await sim.stop()
    await sim.forget_outputs()
    await sim.start()


SIMS: dict[str, tuple[Callable[[], Sim], Callable[[Sim], Awaitable[None]]]] = {
    "opcua": (OpcUaSimController, _opcua_power_cycle),
    "s7": (S7SimController, _s7_power_cycle),
}


@pytest.mark.parametrize("protocol", sorted(SIMS))
async def test_the_line_another_writer_and_a_power_cycle(protocol: str,
                                                         tmp_path: Path) -> None:
    make, power_cycle = SIMS[protocol]
    sn, sb, t0 = _slope_gains()
    sim = make()
    await sim.start()
    cfg = parse_config(_doc(sim, t0, sn, sb), tmp_path / "compd.toml")
    cycle = Cycle(params_from_config(cfg), cfg.model)
    driver = build_driver(cfg)
    machine = BallscrewMachine(sim, hours=HOURS, period_s=PERIOD_S, program=PROGRAM)
    try:
        await driver.connect()
        t = 0.0
        for _ in range(machine.rows - 1):
            temps = machine.temperatures()
            await sim.publish({SENSOR_CHANNELS[n]: temps[n] for n in TEMPERATURES})
            t += PERIOD_S
            plan, row = await drive_cycle(driver, cycle, cfg, t)
            errors = await machine.tick()
        worst_none = max(abs(machine.growth_um(x)) for x in machine.positions_mm)
        worst_comp = max(abs(e) for e in errors.values())
        x = row.axes["x"]
        assert x.cause == Cause.IN_FORCE and x.in_force
        # the controller holds the line compd sent (SINUMERIK units: mm, tan β; REAL
        # or Double), and the axes word beside it says X is in force
        held = await sim.compensation("x")
        assert held.value_um == pytest.approx(x.value.confirmed, abs=1e-3)
        assert held.slope_um_m == pytest.approx(x.slope.confirmed, abs=1e-3)
        word = int((await driver.read(["axes_status"]))["axes_status"].value)
        assert word == int(plan.writes["axes_status"])
        assert word & AxesStatus.X_IN_FORCE and not word & AxesStatus.X_ALARM
        print(f"{protocol} axis x: worst error along the travel {worst_none:.1f} µm "
              f"uncompensated, {worst_comp:.2f} µm with value and slope")
        assert worst_comp < 0.1 * worst_none, (worst_comp, worst_none)

        # another client writes the axis's value: found, alarmed, ramped from
        assert x.value.confirmed is not None
        foreign = x.value.confirmed + 100.0
        await sim.publish({"x_comp_value": foreign})
        t += PERIOD_S
        plan, row = await drive_cycle(driver, cycle, cfg, t)
        found = [e for e in plan.events if e.name is EventName.READBACK_MISMATCH]
        assert [e.fields["output"] for e in found] == ["x_comp_value"]
        assert row.axes["x"].cause == Cause.FOREIGN_OFFSET
        assert abs(plan.writes["x_comp_value"] - foreign) <= STEP + 1e-6
        assert plan.writes["x_comp_value"] < foreign  # back toward the model
        assert int(plan.writes["axes_status"]) & AxesStatus.X_ALARM
        assert not int(plan.writes["axes_status"]) & AxesStatus.X_IN_FORCE
        assert row.cause.healthy  # the offset's own health is its own

        # the controller power-cycles: the link drops and its parameters read 0
        await power_cycle(sim)
        await driver.close()
        driver = build_driver(cfg)
        await driver.connect()
        t += PERIOD_S
        plan, row = await drive_cycle(driver, cycle, cfg, t)
        assert 0.0 < plan.writes["x_comp_value"] <= STEP + 1e-6
        assert 0.0 < plan.writes["x_comp_slope"] <= STEP + 1e-6
        assert row.axes["x"].cause == Cause.FOREIGN_OFFSET
        held = await sim.compensation("x")
        assert held.value_um == pytest.approx(plan.writes["x_comp_value"], abs=1e-3)
        assert held.reference_mm == 0.0
        # back in force at the axis's rate, never a step beyond it
        last = plan.writes["x_comp_value"]
        for _ in range(12):
            t += PERIOD_S
            plan, row = await drive_cycle(driver, cycle, cfg, t)
            assert abs(plan.writes["x_comp_value"] - last) <= STEP + 1e-6
            last = plan.writes["x_comp_value"]
        assert row.axes["x"].in_force
    finally:
        await driver.close()
        await sim.stop()
