"""The OPC UA face with ``[output.axes]``: one folder per axis (``Axes/X``) with
the line the controller holds, what the axis's models ask, whether it is in
force, its state, cause, status word and reference position, following the
daemon on the simulated Modbus controller; an axis's failed sensor takes that
axis out of force while the offset stays in force; a reload without the axes
takes their folder away; an axis written as one offset at its read position
publishes that position and the offset (``Position_mm``, ``Offset_um``)."""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import math
from collections.abc import AsyncIterator
from pathlib import Path

from asyncua import ua
from asyncua.common.node import Node
from asyncua.ua.uaerrors import UaStatusCodeError

from compd.config.loader import load_config
from compd.core.cycle import Cycle
from compd.core.output import Status
from compd.core.params import params_from_config
from compd.faces.opcua_face import NAMESPACE, published_values
from compd.runtime.daemon import Daemon
from compd.testing import FakeClock
from drivers.base import Sample
from drivers.sim.modbus_server import ModbusSimController
from drivers.sim.ports import free_tcp_port
from tests.compd.axes_helpers import SENSOR_CHANNELS, axes_config_text
from tests.compd.faces.test_opcua_face import _client, running_daemon
from tests.compd.runtime.test_axes_position_modbus import positional_config
from tests.harness import until

TEMPS = {"nut": 24.0, "screw_bearing": 24.0, "column": 22.0, "ambient": 20.0}


@contextlib.asynccontextmanager
async def _daemon(tmp_path: Path, sim: ModbusSimController, port: int
                  ) -> AsyncIterator[Daemon]:
    path = tmp_path / "compd.toml"
    path.write_text(axes_config_text(sim.endpoint, period_s=2.0, time_scale=10.0, timeout_s=0.08,
                                     value_slew=50.0, slope_slew=50.0)
                    + f'\n[faces.opcua]\nenabled = true\nport = {port}\npolicy = "None"\n'
                    "insecure = true\n", encoding="utf-8")
    async with running_daemon(path) as daemon:
        yield daemon


async def _value(machine: Node, idx: int, *path: str) -> object:
    node = await machine.get_child([f"{idx}:{p}" for p in path])
    return await node.read_value()


async def _becomes(machine: Node, idx: int, path: tuple[str, ...], expected: object) -> None:
    """Poll until the face shows `expected` (at most 2 min: a loaded machine is slower)."""
    for _ in range(12_000):
        if await _value(machine, idx, *path) == expected:
            return
        await asyncio.sleep(0.01)
    assert await _value(machine, idx, *path) == expected


async def test_each_axis_has_its_nodes_and_follows_the_cycle(tmp_path: Path) -> None:
    sim = ModbusSimController()
    await sim.start()
    await sim.publish({SENSOR_CHANNELS[n]: v for n, v in TEMPS.items()})
    port = free_tcp_port("127.0.0.1")
    try:
        async with _daemon(tmp_path, sim, port) as daemon, await _client(port) as client:
            idx = await client.get_namespace_index(NAMESPACE)
            machine = await client.nodes.objects.get_child(f"{idx}:axes")
            x = ("Axes", "X")
            await _becomes(machine, idx, (*x, "InForce"), True)
            # 3·2 + 1.5·4 = 12 µm; 5·4 + 6.5·4 = 46 µm/m (TwinCAT's grid: 0.1 µm, 1 µm/m)
            assert math.isclose(float(await _value(machine, idx, *x, "Value_um")),  # type: ignore[arg-type]
                                12.0, abs_tol=0.05)
            assert math.isclose(float(await _value(machine, idx, *x, "Slope_um_m")),  # type: ignore[arg-type]
                                46.0, abs_tol=0.5)
            assert await _value(machine, idx, *x, "ValueModel_um") == 12.0
            assert await _value(machine, idx, *x, "FaultStateName") == "ok"
            await _becomes(machine, idx, (*x, "Cause"), "in_force")
            assert int(await _value(machine, idx, *x, "StatusWord")) & Status.OK  # type: ignore[call-overload]
            assert await _value(machine, idx, *x, "ReferencePosition_mm") == 0.0
            # a line's parameters: no position read, no offset at it
            assert math.isnan(await _value(machine, idx, *x, "Position_mm"))  # type: ignore[arg-type]
            assert math.isnan(await _value(machine, idx, *x, "Offset_um"))  # type: ignore[arg-type]

            # the nut's sensor fails (beyond its range): X holds, the offset goes on
            await sim.publish({SENSOR_CHANNELS["nut"]: 500.0})
            await _becomes(machine, idx, (*x, "Cause"), "inputs_invalid")
            assert await _value(machine, idx, *x, "InForce") is False
            assert await _value(machine, idx, *x, "FaultStateName") == "hold"
            assert await _value(machine, idx, "OffsetInForce") is True

            # a reload without [output.axes]: their folder goes
            path = daemon.running.cfg.path
            text = path.read_text(encoding="utf-8")
            path.write_text(text[:text.index("[output.axes.x]")]
                            + text[text.index("[faults]"):], encoding="utf-8")
            path.write_text(path.read_text(encoding="utf-8").replace(
                'axes_status = { kind = "holding", address = 4, type = "uint16" }\n', ""),
                encoding="utf-8")
            daemon.request_reload()
            await until(lambda: daemon.reloader.reloads >= 1)
            assert daemon.running.cfg.axes is None
            names: set[str] = {"Axes"}
            for _ in range(12_000):
                with contextlib.suppress(UaStatusCodeError):  # deleted while browsed
                    names = {(await n.read_browse_name()).Name
                             for n in await machine.get_children()}
                    if "Axes" not in names:
                        break
                await asyncio.sleep(0.01)
            assert "Axes" not in names and "OffsetInForce" in names
    finally:
        await sim.stop()


def test_an_axis_at_its_position_publishes_the_position_and_the_offset(
        tmp_path: Path) -> None:
    cfg = load_config(positional_config(tmp_path, "modbus://127.0.0.1:5020", period_s=1.0,
                                        time_scale=1.0, value_slew=5.0, slope_slew=5.0))
    cycle = Cycle(dataclasses.replace(params_from_config(cfg), readback=False), cfg.model)
    clock = FakeClock(period_s=1.0)
    for _ in range(3):
        t = clock.tick()
        temps = {"nut": 24.0, "screw_bearing": 24.0, "column": 22.0, "ambient": 20.0,
                 "x_pos": 800.0}
        cycle.plan(t, {n: Sample(v, t) for n, v in temps.items()})
        row = cycle.commit()
    values = published_values(row, cfg)
    x = row.axes["x"]
    assert x.offset_um is not None
    assert values["Axes.X.Position_mm"] == (800.0, ua.VariantType.Double)
    assert values["Axes.X.Offset_um"] == (x.offset_um, ua.VariantType.Double)
