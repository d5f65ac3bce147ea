"""An axis written as an offset at its position over FOCAS (the ctypes driver against
the compiled stand-in library): the ladder keeps the axis's position in a PMC float
and applies a plain PMC offset wherever the axis stands. The ball-screw axis moves
every cycle; the error at the moving position comes down as over Modbus
(`test_axes_position_modbus`), and a traverse moves the offset by slope·Δx at once."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

import pytest

from compd.config.loader import parse_config
from compd.core.cycle import Cycle
from compd.core.health import Cause
from compd.core.params import params_from_config
from compd.runtime.driver_setup import build_driver
from drivers.addresses import FocasPmcAddress
from drivers.sim.ballscrew import TEMPERATURES
from drivers.sim.ballscrew_machine import BallscrewMachine
from drivers.sim.focas_server import FocasSimController
from tests.compd.axes_helpers import SENSOR_CHANNELS, drive_cycle
from tests.compd.runtime.test_axes_ballscrew import HOURS, PERIOD_S, PROGRAM, _slope_gains
from tests.compd.runtime.test_axes_position_modbus import positional_config_text, travel


def _doc(sim: FocasSimController, **over: float) -> dict[str, Any]:
    """The Modbus positional config with the FOCAS sim's own addresses."""
    doc = tomllib.loads(positional_config_text(sim.endpoint, **over))
    doc["controller"] = {**doc["controller"], "protocol": "focas",
                         "focas": {"library_path": sim.library_path}}
    for name, sensor in SENSOR_CHANNELS.items():
        doc["channels"][name]["address"] = sim.channels[sensor].model_dump()
    doc["channels"]["x_pos"]["address"] = sim.positions["x_position"].model_dump()
    out = doc["output"]
    for name in ("offset", "heartbeat", "status"):
        out[name] = sim.outputs_map[name].model_dump()
    out["axes_status"] = FocasPmcAddress(area="D", address=112, type="word").model_dump()
    out["axes"]["x"]["offset"] = sim.axis_offsets["x_comp_offset"].model_dump()
    return doc


async def test_the_offset_at_the_moving_position_over_focas(tmp_path: Path) -> None:
    sn, sb, t0 = _slope_gains()
    sim = FocasSimController()
    await sim.start()
    cfg = parse_config(_doc(sim, period_s=PERIOD_S, time_scale=1.0, timeout_s=2.0, t0=t0,
                            sn=sn, sb=sb, value_slew=0.05, slope_slew=0.05),
                       tmp_path / "compd.toml")
    cycle = Cycle(params_from_config(cfg), cfg.model)
    driver = build_driver(cfg)
    machine = BallscrewMachine(sim, hours=HOURS, period_s=PERIOD_S,  # type: ignore[arg-type]
                               program=PROGRAM)
    errors: list[tuple[float, float]] = []
    try:
        await driver.connect()
        t = 0.0
        for _ in range(machine.rows - 1):
            temps = machine.temperatures()
            x = travel(machine.row)
            await sim.publish({**{SENSOR_CHANNELS[n]: temps[n] for n in TEMPERATURES},
                               "x_position": x})
            t += PERIOD_S
            plan, row = await drive_cycle(driver, cycle, cfg, t)
            held = await sim.read_back("x_comp_offset")
            errors.append((machine.growth_um(x), machine.growth_um(x) - held))
            machine.step()
        a = row.axes["x"]
        assert a.cause == Cause.IN_FORCE and a.in_force
        # the PMC long holds 0.1 µm counts: the offset sent is on that grid
        assert plan.writes["x_comp_offset"] == pytest.approx(held, abs=1e-9)
        assert round(held * 10.0) == pytest.approx(held * 10.0, abs=1e-6)
    finally:
        await driver.close()
        await sim.stop()
        sim.close()
    settled = errors[len(errors) // 3:]
    worst_none = max(abs(g) for g, _ in settled)
    worst_comp = max(abs(e) for _, e in settled)
    print(f"FOCAS, axis x moving 20..980 mm, error at the moving position: worst over the "
          f"last two thirds {worst_none:.1f} µm uncompensated, {worst_comp:.2f} µm with "
          "the offset there")
    assert worst_comp < 0.1 * worst_none, (worst_comp, worst_none)
