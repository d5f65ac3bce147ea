"""An axis written as one offset at its present position, end to end: the cycle built
from a config whose ``[output.axes.x]`` names a position channel and a plain offset
register writes over the real Modbus driver to the simulated controller, which applies
that offset as it is wherever the axis stands. The ball-screw axis moves along its
travel every cycle: the error at the moving position comes down as with the
controller's own parameters; a position that is not a number holds the axis; a
traverse moves the offset by the slope's part at once (`compd.core.axes`)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from compd.config.loader import load_config
from compd.core.cycle import Cycle
from compd.core.health import Cause
from compd.core.params import params_from_config
from compd.errors import ConfigError
from compd.runtime.driver_setup import build_driver
from drivers.sim.ballscrew import TEMPERATURES
from drivers.sim.ballscrew_machine import BallscrewMachine
from drivers.sim.modbus_server import ModbusSimController
from tests.compd.axes_helpers import SENSOR_CHANNELS, axes_config_text, drive_cycle
from tests.compd.runtime.test_axes_ballscrew import HOURS, PERIOD_S, PROGRAM, _slope_gains

POSITION = """
[channels.x_pos]
address = {{ kind = "input", address = 16, type = "float32" }}
unit = "mm"
range = [{lo}, {hi}]
stale_after_s = {stale_after_s}

"""
OFFSET = 'offset = { kind = "holding", address = 50, type = "float32" }\n'


def positional_config_text(endpoint: str, *, lo: float = -10.0, hi: float = 1010.0,
                           stale_after_s: float = 1200.0, **over: float) -> str:
    """The ball-screw axes config (`tests.compd.axes_helpers`) with X written as an
    offset at the position read from channel ``x_pos``."""
    text = axes_config_text(endpoint, **over)
    head, rest = text.split("[output.axes.x]\n")
    table, models = rest.split("[output.axes.x.model]\n")
    table = "".join(line for line in table.splitlines(keepends=True)
                    if not line.startswith(("reference =", "value =", "slope =")))
    head = head.replace("[model]\n", POSITION.format(lo=lo, hi=hi, stale_after_s=stale_after_s)
                        + "[model]\n", 1)
    return (f"{head}[output.axes.x]\nposition = \"x_pos\"\n{OFFSET}{table}"
            f"[output.axes.x.model]\n{models}")


def positional_config(tmp_path: Path, endpoint: str, **over: float) -> Path:
    p = tmp_path / "compd.toml"
    p.write_text(positional_config_text(endpoint, **over), encoding="utf-8")
    return p


def travel(row: int) -> float:
    """The axis's position at one row of the record: back and forth along 0..1000 mm."""
    return 500.0 + 480.0 * math.sin(0.9 * row)




async def test_the_offset_at_the_moving_position_brings_its_error_down(
        tmp_path: Path) -> None:
    sn, sb, t0 = _slope_gains()
    sim = ModbusSimController()
    await sim.start()
    cfg = load_config(positional_config(
        tmp_path, sim.endpoint, period_s=PERIOD_S, time_scale=1.0, timeout_s=2.0, t0=t0,
        sn=sn, sb=sb, value_slew=0.05, slope_slew=0.05))
    cycle = Cycle(params_from_config(cfg), cfg.model)
    driver = build_driver(cfg)
    machine = BallscrewMachine(sim, hours=HOURS, period_s=PERIOD_S, program=PROGRAM)
    errors: list[tuple[float, float]] = []  # (growth, error left) at the moving position
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
            # the controller applies its offset register at the axis's position
            held = (await sim.read_values(["x_comp_offset"]))["x_comp_offset"]
            errors.append((machine.growth_um(x), machine.growth_um(x) - held))
            machine.step()
        a = row.axes["x"]
        assert a.cause == Cause.IN_FORCE and a.in_force
        assert a.position_mm == pytest.approx(x) and a.offset_um == pytest.approx(held, abs=1e-3)
        # one register, no line parameters written
        assert "x_comp_value" not in plan.writes and set(cycle.axes.names) == {"x_comp_offset"}

        # NaN in the position register: the axis holds its offset, the others go on
        await sim.publish({"x_position": math.nan})
        t += PERIOD_S
        plan, row = await drive_cycle(driver, cycle, cfg, t)
        assert row.axes["x"].cause == Cause.INPUTS_INVALID
        assert plan.writes["x_comp_offset"] == pytest.approx(held, abs=1e-3)
        assert row.cause.healthy
        assert (await sim.read_values(["x_comp_offset"]))["x_comp_offset"] == \
            pytest.approx(held, abs=1e-3)
    finally:
        await driver.close()
        await sim.stop()
    settled = errors[len(errors) // 3:]
    worst_none = max(abs(g) for g, _ in settled)
    worst_comp = max(abs(e) for _, e in settled)
    last_none, last_comp = errors[-1]
    print(f"axis x moving 20..980 mm, error at the moving position: worst over the last "
          f"two thirds {worst_none:.1f} µm uncompensated, {worst_comp:.2f} µm with the "
          f"offset there; last cycle {abs(last_none):.1f} µm, {abs(last_comp):.2f} µm")
    assert worst_comp < 0.1 * worst_none, (worst_comp, worst_none)


async def test_a_traverse_moves_the_offset_by_the_slope_at_once(tmp_path: Path) -> None:
    """The motion's part is not rate limited (docs/protocols.md §11): at the new
    position the controller applies value + slope·(x - reference) at once, the value
    and slope stages do not move."""
    sim = ModbusSimController()
    await sim.start()
    cfg = load_config(positional_config(
        tmp_path, sim.endpoint, period_s=60.0, time_scale=1.0, timeout_s=2.0,
        value_slew=100.0, slope_slew=100.0))
    cycle = Cycle(params_from_config(cfg), cfg.model)
    driver = build_driver(cfg)
    try:
        await driver.connect()
        t = 0.0
        # warm: nut and bearing 10 K up, slope 5·10 + 6.5·10 = 115 µm/m; value 30 + 15 µm
        temps = {"motor": 30.0, "bearing": 30.0, "column": 30.0, "ambient": 20.0}
        await sim.publish({**temps, "x_position": 100.0})
        for _ in range(5):
            t += 60.0
            plan, row = await drive_cycle(driver, cycle, cfg, t)
        before = row.axes["x"]
        assert before.in_force and before.slope.confirmed == pytest.approx(115.0)
        # the traverse: 800 mm in one cycle
        await sim.publish({"x_position": 900.0})
        t += 60.0
        plan, row = await drive_cycle(driver, cycle, cfg, t)
        after = row.axes["x"]
        assert before.offset_um is not None
        step = plan.writes["x_comp_offset"] - before.offset_um
        assert step == pytest.approx(115.0 * 0.8, abs=1e-3)  # 92 µm at once
        assert after.value.sent == before.value.sent and after.slope.sent == before.slope.sent
        assert after.in_force and after.cause == Cause.IN_FORCE
    finally:
        await driver.close()
        await sim.stop()


def test_the_config_refuses_a_position_without_age_bound_or_unit(tmp_path: Path) -> None:
    text = positional_config_text("modbus://127.0.0.1:5020")
    p = tmp_path / "compd.toml"
    p.write_text(text.replace("stale_after_s = 1200.0\n", ""), encoding="utf-8")
    with pytest.raises(ConfigError, match=r"channels\.x_pos\.stale_after_s"):
        load_config(p)
    p.write_text(text.replace('unit = "mm"', 'unit = "um"'), encoding="utf-8")
    with pytest.raises(ConfigError, match=r"output\.axes\.x\.position"):
        load_config(p)
    p.write_text(text.replace('position = "x_pos"\n',
                              'position = "x_pos"\nslope = { kind = "holding", address = 36, '
                              'type = "int32" }\n'), encoding="utf-8")
    with pytest.raises(ConfigError, match=r"output\.axes\.x\.slope.*takes an offset"):
        load_config(p)
    # an int16 in 0.01 µm (±327.67 µm) cannot hold the line over the travel
    # (200 µm + 200 µm/m · 1.01 m)
    p.write_text(text.replace(OFFSET, 'offset = { kind = "holding", address = 50, '
                              'type = "int16", scale = 0.01 }\n'), encoding="utf-8")
    with pytest.raises(ConfigError, match=r"output\.axes\.x\.offset"):
        load_config(p)
