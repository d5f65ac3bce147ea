"""X and Z compensated at once on a real, headless LinuxCNC
(`drivers.sim.linuxcnc_machine`): each axis's external offset (``axis.x.eoffset``,
``axis.z.eoffset``) driven by compd's HAL component in the same write, X's offset
evaluated at X's position as LinuxCNC reports it (``axis.x.pos-cmd``).

The cycle is built from a config (``[output] offset`` Z's external offset,
``[output.axes.x]`` at the position channel ``x_pos`` with X's external offset) and
runs over the real driver, as `tests.compd.runtime.test_axes_position_modbus` does on
Modbus; everything is checked on LinuxCNC's side (``axis.L.eoffset``).

One LinuxCNC for the module, held under the machine's LinuxCNC lock
(`drivers.sim.linuxcnc_host`); skipped with the reason where ``linuxcnc-uspace``
is absent or a LinuxCNC this run did not start runs. X is moved by MDI lines (each
runs to its end before the cycle reads), or by one G-code program run in AUTO mode
while the daemon compensates. The figures are printed: ``-s`` shows them.
"""

from __future__ import annotations

import itertools
import json
import math
import time
from collections.abc import AsyncIterator
from pathlib import Path

import pytest
import pytest_asyncio

from compd.config.loader import LoadedConfig, load_config
from compd.core.cycle import Cycle
from compd.core.health import Cause
from compd.core.params import params_from_config
from compd.runtime.driver_setup import build_driver
from drivers.linuxcnc import LinuxCncDriver
from drivers.sim.linuxcnc_machine import (
    COUNT_UM,
    ForeignLinuxCnc,
    LinuxCncBusy,
    LinuxCncSimController,
    unavailable,
)
from drivers.sim.machine import SimMachine
from drivers.sim.programs import constant
from tests.compd.axes_helpers import drive_cycle
from tests.harness import Lockstep

WHY_NOT = unavailable()
pytestmark = [pytest.mark.skipif(WHY_NOT is not None, reason=str(WHY_NOT)),
              pytest.mark.asyncio(loop_scope="module"),
              pytest.mark.timeout(600, func_only=True)]

#: how close motion's external offset planner comes to the request before it stops
SETTLED_UM = 1e-3
PERIOD_S = 60.0
#: the models: Z 2 µm/K of the column; X's value 1.5 µm/K of the column, its slope
#: 20 µm/m per K of the bearing, each from 20 °C, reference position 0 mm
KZ, KX, KS, T0 = 2.0, 1.5, 20.0, 20.0

CONFIG = """
[machine]
name = "xz"
period_s = {period_s}
time_scale = 1.0

[controller]
protocol = "linuxcnc"
endpoint = "linuxcnc://localhost"
timeout_s = 10.0
connect_timeout_s = 60.0

[controller.linuxcnc]
component = "{component}"

[channels.column]
address = {{ pin = "column", net = "{p}-column" }}
unit = "degC"
range = [-20.0, 150.0]

[channels.bearing]
address = {{ pin = "bearing", net = "{p}-bearing" }}
unit = "degC"
range = [-20.0, 150.0]

[channels.x_pos]
address = {{ kind = "get", hal = "axis.x.pos-cmd" }}
unit = "mm"
range = [-100.0, 100.0]
stale_after_s = 600.0

[model]
reference = {{ column = {t0} }}
[[model.terms]]
name = "z"
inputs = {{ column = {kz} }}
a = ["1"]
b = ["1"]

[output]
heartbeat = {{ pin = "heartbeat", net = "{p}-heartbeat", type = "s32" }}
status = {{ pin = "status", net = "{p}-status", type = "s32" }}
limit_um = 100.0
slew_um_s = {zslew}

[output.offset]
kind = "eoffset"
axis = "z"
scale = {count}
counts_net = "{p}-eoffset-counts"
enable_net = "{p}-eoffset-enable"

[output.axes.x]
position = "x_pos"
reference_mm = 0.0
value_limit_um = 100.0
slope_limit_um_m = 200.0
slew_um_s = {xslew}
slope_slew_um_m_s = {sslew}

[output.axes.x.offset]
kind = "eoffset"
axis = "x"
scale = {count}
counts_net = "{p}-x-eoffset-counts"
enable_net = "{p}-x-eoffset-enable"

[output.axes.x.model]
reference = {{ column = {t0} }}
[[output.axes.x.model.terms]]
name = "value"
inputs = {{ column = {kx} }}
a = ["1"]
b = ["1"]

[output.axes.x.slope_model]
reference = {{ bearing = {t0} }}
[[output.axes.x.slope_model.terms]]
name = "slope"
inputs = {{ bearing = {ks} }}
a = ["1"]
b = ["1"]
{y_axis}
[faults]
hold_s = 600.0

[state]
dir = "state"
checkpoint_every = 1

[recorder]
enabled = false
"""


#: Y, when asked for: its value 0.5 µm/K of the column (the opposite way to X's), its
#: slope 10 µm/m per K of the bearing, at Y's position as LinuxCNC reports it
KY, KSY = -0.5, 10.0
Y_AXIS = """
[channels.y_pos]
address = {{ kind = "get", hal = "axis.y.pos-cmd" }}
unit = "mm"
range = [-100.0, 100.0]
stale_after_s = 600.0

[output.axes.y]
position = "y_pos"
reference_mm = 0.0
value_limit_um = 100.0
slope_limit_um_m = 200.0
slew_um_s = 10.0
slope_slew_um_m_s = 10.0

[output.axes.y.offset]
kind = "eoffset"
axis = "y"
scale = {count}
counts_net = "{p}-y-eoffset-counts"
enable_net = "{p}-y-eoffset-enable"

[output.axes.y.model]
reference = {{ column = {t0} }}
[[output.axes.y.model.terms]]
name = "value"
inputs = {{ column = {ky} }}
a = ["1"]
b = ["1"]

[output.axes.y.slope_model]
reference = {{ bearing = {t0} }}
[[output.axes.y.slope_model.terms]]
name = "slope"
inputs = {{ bearing = {ksy} }}
a = ["1"]
b = ["1"]
"""


def _config(sim: LinuxCncSimController, tmp_path: Path, *, zslew: float = 10.0,
            xslew: float = 10.0, sslew: float = 10.0, y: bool = False) -> LoadedConfig:
    """The module's config; the slews (µm/s, X's slope µm/m per s) as given; with `y`,
    Y compensated at its position too."""
    p = tmp_path / "compd.toml"
    y_axis = Y_AXIS.format(count=COUNT_UM, p=sim.prefix, t0=T0, ky=KY, ksy=KSY) if y else ""
    p.write_text(CONFIG.format(period_s=PERIOD_S, component=sim.component, p=sim.prefix,
                               t0=T0, kz=KZ, kx=KX, ks=KS, count=COUNT_UM, zslew=zslew,
                               xslew=xslew, sslew=sslew, y_axis=y_axis), encoding="utf-8")
    return load_config(p)




@pytest_asyncio.fixture(scope="module", loop_scope="module")
async def lcnc() -> AsyncIterator[LinuxCncSimController]:
    sim = LinuxCncSimController()
    try:
        await sim.start()
    except (ForeignLinuxCnc, LinuxCncBusy) as exc:
        pytest.skip(str(exc))
    try:
        yield sim
    finally:
        await sim.stop()


async def test_x_and_z_eoffsets_are_written_together(lcnc: LinuxCncSimController) -> None:
    """One driver, one write: X's, Y's and Z's external offsets all applied, each on
    its own signals and counts, and each read back on its own axis."""
    outputs = {"offset": lcnc.outputs_map["offset"], "x_offset": lcnc.x_offset,
               "y_offset": lcnc.y_offset}
    driver = LinuxCncDriver(lcnc.endpoint, {"x_pos": lcnc.x_position}, outputs,
                            timeout_s=10.0, connect_timeout_s=60.0, component=lcnc.component)
    try:
        await driver.connect()
        assert driver.eoffset_scales == pytest.approx({"offset": 1e-4, "x_offset": 1e-4,
                                                      "y_offset": 1e-4})
        await driver.write({"offset": 4.2, "x_offset": -7.3, "y_offset": 3.1})
        hal = await lcnc.settled_axes()
        assert hal["offset_um"] == pytest.approx(4.2, abs=SETTLED_UM)
        assert hal["x_offset_um"] == pytest.approx(-7.3, abs=SETTLED_UM)
        assert hal["y_offset_um"] == pytest.approx(3.1, abs=SETTLED_UM)
        got = await driver.read(["offset", "x_offset", "y_offset", "x_pos"])
        assert got["offset"].value == pytest.approx(4.2, abs=SETTLED_UM)
        assert got["x_offset"].value == pytest.approx(-7.3, abs=SETTLED_UM)
        assert got["y_offset"].value == pytest.approx(3.1, abs=SETTLED_UM)
        await driver.write({"y_offset": 0.0})
        # X alone: Z keeps its offset
        await driver.write({"x_offset": 2.5})
        hal = await lcnc.settled_axes()
        assert (hal["x_offset_um"], hal["offset_um"]) == pytest.approx((2.5, 4.2),
                                                                      abs=SETTLED_UM)
        await driver.write({"offset": 0.0, "x_offset": 0.0})
        hal = await lcnc.settled_axes()
        assert (hal["x_offset_um"], hal["offset_um"]) == pytest.approx((0.0, 0.0),
                                                                      abs=SETTLED_UM)
    finally:
        await driver.close()


async def test_x_at_its_position_and_z_compensated_at_once(
        lcnc: LinuxCncSimController, tmp_path: Path) -> None:
    """X's offset follows X as it moves (value + slope · x, at the position LinuxCNC
    reports), Z's follows its model, both applied by LinuxCNC each cycle; a bearing
    that reads NaN (X's slope model's input) holds X's line, and its offset with it,
    while Z goes on."""
    cfg = _config(lcnc, tmp_path)
    cycle = Cycle(params_from_config(cfg), cfg.model)
    assert set(cycle.axes.names) == {"x_comp_offset"}
    driver = build_driver(cfg)
    rows: list[dict[str, float]] = []
    try:
        await driver.connect()
        t = 0.0
        for i in range(12):
            column, bearing = T0 + 0.8 * i, T0 + 0.5 * i
            x = round(80.0 * math.sin(1.3 * i), 3)
            await lcnc.control("mdi", f"G90 G0 X{x:.3f}")
            await lcnc.publish({"column": column, "bearing": bearing})
            t += PERIOD_S
            plan, row = await drive_cycle(driver, cycle, cfg, t)
            hal = await lcnc.settled_axes()
            want_x = KX * (column - T0) + KS * (bearing - T0) * hal["x_pos_mm"] / 1000.0
            want_z = KZ * (column - T0)
            a = row.axes["x"]
            assert a.cause == Cause.IN_FORCE, a
            assert a.position_mm == pytest.approx(hal["x_pos_mm"], abs=1e-6)
            assert plan.writes["x_comp_offset"] == pytest.approx(want_x, abs=COUNT_UM / 2 + 1e-9)
            assert plan.writes["offset"] == pytest.approx(want_z, abs=COUNT_UM / 2 + 1e-9)
            # LinuxCNC applies both, each on its own axis
            assert hal["x_offset_um"] == pytest.approx(plan.writes["x_comp_offset"],
                                                       abs=SETTLED_UM)
            assert hal["offset_um"] == pytest.approx(plan.writes["offset"], abs=SETTLED_UM)
            rows.append({"x_mm": hal["x_pos_mm"], "x_um": hal["x_offset_um"],
                         "x_model_um": want_x, "z_um": hal["offset_um"],
                         "z_model_um": want_z})
        held_x = rows[-1]["x_um"]
        z_before = rows[-1]["z_um"]
        line = (row.axes["x"].value.stage, row.axes["x"].slope.stage)

        # NaN on the bearing (X's slope input): X's line holds, its offset stays where
        # it is, while Z goes on
        await lcnc.publish({"column": T0 + 12.0, "bearing": math.nan})
        t += PERIOD_S
        plan, row = await drive_cycle(driver, cycle, cfg, t)
        hal = await lcnc.settled_axes()
        assert row.axes["x"].cause == Cause.INPUTS_INVALID and row.cause.healthy
        assert hal["x_offset_um"] == pytest.approx(held_x, abs=SETTLED_UM)
        assert plan.writes["offset"] == pytest.approx(KZ * 12.0, abs=COUNT_UM / 2 + 1e-9)
        assert hal["offset_um"] == pytest.approx(plan.writes["offset"], abs=SETTLED_UM)
        assert abs(hal["offset_um"] - z_before) > 1.0
        # X moves under the held line: its offset is that line at the new position,
        # as a controller applying its own line would; Z goes on
        await lcnc.control("mdi", "G90 G0 X-30")
        await lcnc.publish({"column": T0 + 13.0})
        t += PERIOD_S
        plan, row = await drive_cycle(driver, cycle, cfg, t)
        hal = await lcnc.settled_axes()
        a = row.axes["x"]
        assert a.cause == Cause.INPUTS_INVALID
        assert (a.value.stage, a.slope.stage) == line
        assert hal["x_pos_mm"] == pytest.approx(-30.0, abs=1e-6)
        assert hal["x_offset_um"] == pytest.approx(line[0] + line[1] * -30.0 / 1000.0,
                                                   abs=COUNT_UM / 2 + SETTLED_UM)
        assert hal["offset_um"] == pytest.approx(KZ * 13.0, abs=COUNT_UM / 2 + SETTLED_UM)
        nan_figure = {"x_held_um": held_x, "x_at_minus_30_mm_um": hal["x_offset_um"],
                      "z_um": [z_before, KZ * 12.0, hal["offset_um"]]}
        # the bearing back: X's line follows its models again at its present position
        await lcnc.publish({"bearing": T0 + 6.0})
        t += PERIOD_S
        plan, row = await drive_cycle(driver, cycle, cfg, t)
        hal = await lcnc.settled_axes()
        want_x = KX * 13.0 + KS * 6.0 * hal["x_pos_mm"] / 1000.0
        assert row.axes["x"].cause == Cause.IN_FORCE
        assert hal["x_offset_um"] == pytest.approx(want_x, abs=COUNT_UM / 2 + SETTLED_UM)
        # back to zero for the next test
        await driver.write({"offset": 0.0, "x_comp_offset": 0.0})
        await lcnc.settled_axes()
    finally:
        await driver.close()
        await lcnc.control("mdi", "G90 G0 X0")
    worst_x = max(abs(r["x_um"] - r["x_model_um"]) for r in rows)
    worst_z = max(abs(r["z_um"] - r["z_model_um"]) for r in rows)
    print(json.dumps({"figure": "linuxcnc_x_and_z", "cycles": len(rows),
                      "x_travel_mm": [min(r["x_mm"] for r in rows),
                                      max(r["x_mm"] for r in rows)],
                      "x_max_um": max(abs(r["x_um"]) for r in rows),
                      "worst_x_vs_model_um": worst_x, "worst_z_vs_model_um": worst_z,
                      "nan_bearing": nan_figure}))


async def test_the_daemon_writes_x_and_z_on_linuxcnc(lcnc: LinuxCncSimController,
                                                     tmp_path: Path) -> None:
    """The whole daemon (lockstep, `tests.harness`) on the same config, the plant
    heating: each cycle's X and Z writes are what LinuxCNC applies, X's at X's
    position as MDI moves it."""
    cfg = _config(lcnc, tmp_path)
    machine = SimMachine(lcnc, program=constant(9000.0, heat_h=10.0, cool_h=1.0),
                         seed=3, period_s=PERIOD_S, repeat=False)
    rig = Lockstep(machine, cfg.path)
    seen: list[tuple[float, float, float]] = []  # (x mm, X's offset, Z's offset) in µm
    try:
        await rig.start()
        for i in range(6):
            await lcnc.control("mdi", f"G90 G0 X{60.0 * math.cos(1.1 * i):.3f}")
            await rig.step()
            assert rig.daemon is not None
            result = rig.daemon.loop.last_result
            assert result is not None
            hal = await lcnc.settled_axes()
            assert result.axes["x"].cause == Cause.IN_FORCE
            assert result.axes["x"].position_mm == pytest.approx(hal["x_pos_mm"], abs=1e-6)
            assert hal["x_offset_um"] == pytest.approx(result.writes["x_comp_offset"],
                                                       abs=SETTLED_UM)
            assert hal["offset_um"] == pytest.approx(result.writes["offset"], abs=SETTLED_UM)
            seen.append((hal["x_pos_mm"], hal["x_offset_um"], hal["offset_um"]))
        assert await rig.stop() == 0
    finally:
        await rig.close()
        await lcnc.control("mdi", "G90 G0 X0")
    print(json.dumps({"figure": "linuxcnc_daemon_x_and_z", "cycles": seen}))
    # X's offset moves with X (the slope's part, several µm over the travel) while Z's,
    # with no position in it, stays within a count or two
    xs, zs = [x for _, x, _ in seen], [z for *_, z in seen]
    assert max(xs) - min(xs) > 2.0 and max(zs) - min(zs) < 0.5


async def test_the_daemon_writes_x_y_and_z_on_linuxcnc(lcnc: LinuxCncSimController,
                                                       tmp_path: Path) -> None:
    """Three axes at once from one daemon (lockstep) on a warming plant: X and Y each
    at its own position as MDI moves both, Z without one; every cycle's three writes
    are what LinuxCNC applies, each on its own axis, and each axis's offset is its own
    line at its own position (Y's slope from the bearing, its value against X's)."""
    cfg = _config(lcnc, tmp_path, y=True)
    assert cfg.axes is not None
    machine = SimMachine(lcnc, program=constant(9000.0, heat_h=10.0, cool_h=1.0),
                         seed=4, period_s=PERIOD_S, repeat=False)
    rig = Lockstep(machine, cfg.path)
    seen: list[dict[str, float]] = []
    try:
        await rig.start()
        for i in range(6):
            x, y = 60.0 * math.cos(1.1 * i), -50.0 * math.sin(0.9 * i + 0.3)
            await lcnc.control("mdi", f"G90 G0 X{x:.3f} Y{y:.3f}")
            await rig.step()
            assert rig.daemon is not None
            result = rig.daemon.loop.last_result
            assert result is not None
            hal = await lcnc.settled_axes()
            for axis, pos in (("x", "x_pos_mm"), ("y", "y_pos_mm")):
                a = result.axes[axis]
                assert a.cause == Cause.IN_FORCE, a
                assert a.position_mm == pytest.approx(hal[pos], abs=1e-6)
                # the offset written is the axis's own line at its own position
                line = a.value.stage + a.slope.stage * (hal[pos] - 0.0) / 1000.0
                assert result.writes[f"{axis}_comp_offset"] == pytest.approx(
                    line, abs=COUNT_UM / 2 + 1e-9)
                assert hal[f"{axis}_offset_um"] == pytest.approx(
                    result.writes[f"{axis}_comp_offset"], abs=SETTLED_UM)
            assert hal["offset_um"] == pytest.approx(result.writes["offset"], abs=SETTLED_UM)
            seen.append({"x_mm": hal["x_pos_mm"], "y_mm": hal["y_pos_mm"],
                         "x_um": hal["x_offset_um"], "y_um": hal["y_offset_um"],
                         "z_um": hal["offset_um"],
                         "x_value_um": result.axes["x"].value.stage,
                         "y_value_um": result.axes["y"].value.stage})
        assert await rig.stop() == 0
    finally:
        await rig.close()
        await lcnc.control("mdi", "G90 G0 X0 Y0")
    print(json.dumps({"figure": "linuxcnc_daemon_x_y_and_z", "cycles": seen}))
    # X's and Y's values are each their own model of the same column (KX against KY:
    # opposite signs), and Y's offset moved with Y
    for r in seen:
        assert abs(r["x_value_um"]) > 0.5
        assert r["x_value_um"] == pytest.approx(KX / KY * r["y_value_um"], abs=0.05)
    ys = [r["y_um"] for r in seen]
    assert max(ys) - min(ys) > 0.2


#: the slews of the program's test (Z and X's value µm/s, X's slope µm/m per s): slow
#: enough that they bind against the warming plant within a 60 s period
Z_SLEW, X_SLEW, SLOPE_SLEW = 0.01, 0.01, 0.2
#: X's travel back and forth (mm) and how far X must have moved between two cycles
TRAVEL_MM, MOVED_MM = 60.0, 10.0
#: seconds X may take to move MOVED_MM on a loaded machine (it moves 50 mm/s)
MOVE_DEADLINE_S = 60.0
#: one G-code program: X back and forth and Z with it, long enough for the test
SWEEP = f"""%
G21 G90 G17
G1 X{TRAVEL_MM:g} Z-5 F3000
o100 repeat [1000]
  G1 X-{TRAVEL_MM:g} Z0 F3000
  G1 X{TRAVEL_MM:g} Z-5 F3000
o100 endrepeat
M2
%
"""
#: linuxcnc's MODE_AUTO and INTERP_IDLE
MODE_AUTO, INTERP_IDLE = 2, 1


async def _moved_from(lcnc: LinuxCncSimController, x_mm: float) -> None:
    """Until X (as LinuxCNC commands it) is MOVED_MM from `x_mm`; bounded."""
    end = time.monotonic() + MOVE_DEADLINE_S
    while abs((await lcnc.settled_axes())["x_pos_mm"] - x_mm) < MOVED_MM:
        if time.monotonic() > end:  # say what LinuxCNC was doing and what it said
            stat = await lcnc.control("stat")
            raise AssertionError(f"X did not move {MOVED_MM} mm from {x_mm} mm in "
                                 f"{MOVE_DEADLINE_S:g} s; LinuxCNC: {stat}; its log ends: "
                                 f"{lcnc.log_tail(800)}")


async def test_one_gcode_program_moves_x_and_z_while_the_daemon_compensates_both(
        lcnc: LinuxCncSimController, tmp_path: Path) -> None:
    """One G-code program, run in AUTO mode, sweeps X (and Z) while the whole daemon
    (lockstep) compensates X at its position and Z at once: each cycle LinuxCNC applies
    what compd wrote on each axis, and every applied step is within that axis's bound:
    Z's slew over the cycle's Δt; X's value slew plus its slope's slew at X's position
    over Δt, plus the slope times the distance X moved (docs/protocols.md)."""
    cfg = _config(lcnc, tmp_path, zslew=Z_SLEW, xslew=X_SLEW, sslew=SLOPE_SLEW)
    machine = SimMachine(lcnc, program=constant(9000.0, heat_h=2.0, cool_h=1.0),
                         seed=5, period_s=PERIOD_S, repeat=False)
    rig = Lockstep(machine, cfg.path)
    assert lcnc.folder is not None
    ngc = lcnc.folder / "sweep.ngc"
    ngc.write_text(SWEEP, encoding="ascii")
    # (x mm, slope µm/m, X's offset, Z's offset) of each cycle, offsets as applied (µm)
    seen: list[tuple[float, float, float, float]] = []
    try:
        await rig.start()
        await lcnc.control("run", str(ngc))
        for i in range(13):
            if i:  # the first: the cycles of the start, X standing at 0
                await _moved_from(lcnc, seen[-1][0])
                await rig.step()
            assert rig.daemon is not None
            result = rig.daemon.loop.last_result
            assert result is not None
            a = result.axes["x"]
            assert a.cause == Cause.IN_FORCE and a.position_mm is not None, a
            hal = await lcnc.settled_axes()
            # what LinuxCNC applies is what compd wrote, on each axis
            assert hal["x_offset_um"] == pytest.approx(result.writes["x_comp_offset"],
                                                       abs=SETTLED_UM)
            assert hal["offset_um"] == pytest.approx(result.writes["offset"], abs=SETTLED_UM)
            seen.append((a.position_mm, a.slope.stage, hal["x_offset_um"], hal["offset_um"]))
        stat = await lcnc.control("stat")
        assert stat["task_mode"] == MODE_AUTO and stat["interp_state"] != INTERP_IDLE, stat
        assert await rig.stop() == 0
    finally:
        await rig.close()
        await lcnc.control("mdi", "G90 G0 X0 Z0")
    steps: dict[str, list[tuple[float, float]]] = {"x": [], "z": []}  # (|step|, bound)
    for (x0, s0, ox0, oz0), (x1, _, ox1, oz1) in itertools.pairwise(seen):
        motion = abs(s0) * abs(x1 - x0) / 1000.0
        steps["x"].append((abs(ox1 - ox0), X_SLEW * PERIOD_S
                           + SLOPE_SLEW * PERIOD_S * abs(x1) / 1000.0 + motion))
        steps["z"].append((abs(oz1 - oz0), Z_SLEW * PERIOD_S))
    figure: dict[str, object] = {"figure": "linuxcnc_program_x_and_z_slew",
                                 "cycles": len(seen),
                                 "x_mm": [round(x, 3) for x, *_ in seen]}
    for axis, got in steps.items():
        worst = max(got, key=lambda sb: sb[0] - sb[1])
        figure[axis] = {"max_step_um": max(s for s, _ in got),
                        "worst_step_vs_bound_um": list(worst),
                        "max_bound_um": max(b for _, b in got)}
        # a count's rounding on either side of a step
        assert all(s <= b + COUNT_UM + 1e-9 for s, b in got), (axis, got)
    print(json.dumps(figure))
    # X moved back and forth across its travel, and the offsets moved with it
    xs = [x for x, *_ in seen]
    assert min(xs) < -MOVED_MM / 2 and max(xs) > MOVED_MM / 2
    assert max(o for *_, o, _ in seen) - min(o for *_, o, _ in seen) > 0.5
