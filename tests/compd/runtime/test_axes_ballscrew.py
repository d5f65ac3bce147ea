"""The per-axis line end to end: the cycle built from a config with
``[output.axes.x]`` (value and slope models from the ball-screw's sensors)
writes over the real Modbus driver to the simulated TwinCAT controller, whose
own arithmetic applies the line at every position (`drivers.sim.ballscrew_machine`):
the error along the travel comes down as the driver tests show; a controller
restart (parameters back at 0) resumes at the axis's rates, never a jump."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from compd.config.loader import load_config
from compd.core.cycle import Cycle
from compd.core.health import Cause
from compd.core.params import params_from_config
from compd.runtime.driver_setup import build_driver
from drivers.sim.ballscrew import TEMPERATURES, constant_program, simulate_ballscrew
from drivers.sim.ballscrew_machine import BallscrewMachine
from drivers.sim.modbus_server import ModbusSimController
from tests.compd.axes_helpers import SENSOR_CHANNELS, drive_cycle, write_axes_config

HOURS, PERIOD_S = 8.0, 600.0
PROGRAM = constant_program(6_000.0, 0.8, 15_000.0)


def _slope_gains() -> tuple[float, float, float]:
    """The slope (µm/m) as a static line of the nut's and the screw bearing's
    temperatures, fitted on the simulated record (what `compd fit` would do)."""
    rec = simulate_ballscrew(HOURS, period_s=PERIOD_S, program=PROGRAM, probe_noise_um=0.0)
    t0 = rec["ambient"][0]
    a = np.column_stack([rec["nut"] - t0, rec["screw_bearing"] - t0])
    (sn, sb), *_ = np.linalg.lstsq(a, rec["slope_um_m"], rcond=None)
    return float(sn), float(sb), float(t0)




async def test_value_and_slope_bring_the_error_down_along_the_travel(tmp_path: Path) -> None:
    sn, sb, t0 = _slope_gains()
    sim = ModbusSimController()
    await sim.start()
    cfg = load_config(write_axes_config(
        tmp_path, sim.endpoint, period_s=PERIOD_S, time_scale=1.0, timeout_s=2.0, t0=t0,
        sn=sn, sb=sb, value_slew=0.05, slope_slew=0.05))
    cycle = Cycle(params_from_config(cfg), cfg.model)
    driver = build_driver(cfg)
    machine = BallscrewMachine(sim, hours=HOURS, period_s=PERIOD_S, program=PROGRAM)
    worst_none = worst_comp = 0.0
    try:
        await driver.connect()
        t = 0.0
        for _ in range(machine.rows - 1):
            temps = machine.temperatures()
            await sim.publish({SENSOR_CHANNELS[n]: temps[n] for n in TEMPERATURES})
            t += PERIOD_S
            plan, row = await drive_cycle(driver, cycle, cfg, t)
            errors = await machine.tick()
        growth = {x: machine.growth_um(x) for x in machine.positions_mm}
        worst_none = max(abs(g) for g in growth.values())
        worst_comp = max(abs(e) for e in errors.values())
        x = row.axes["x"]
        assert x.cause == Cause.IN_FORCE and x.in_force
        # the controller holds the line compd sent, on its grid (0.1 µm, 1 µm/m)
        held = await sim.compensation("x")
        assert held.value_um == pytest.approx(x.value.confirmed, abs=0.05)
        assert held.slope_um_m == pytest.approx(x.slope.confirmed, abs=0.5)

        # the controller restarts: its parameters are 0; compd ramps from there
        await sim.forget_outputs()
        t += PERIOD_S
        plan, row = await drive_cycle(driver, cycle, cfg, t)
        step = 0.05 * PERIOD_S
        assert 0.0 < plan.writes["x_comp_value"] <= step + 0.1
        assert 0.0 < plan.writes["x_comp_slope"] <= step + 1.0
        assert row.axes["x"].cause == Cause.FOREIGN_OFFSET
        assert any(e.fields.get("output") == "x_comp_value" for e in plan.events)
    finally:
        await driver.close()
        await sim.stop()
    assert machine.slope_um_m > 30.0
    # the line along the travel: a tenth of the uncompensated error is left at most
    print(f"axis x: worst error along the travel {worst_none:.1f} µm uncompensated, "
          f"{worst_comp:.2f} µm with value and slope")
    assert worst_comp < 0.1 * worst_none, (worst_comp, worst_none)
