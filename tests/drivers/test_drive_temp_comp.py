"""The HIL drive maps and loop with the per-axis temperature-compensation
parameters: the shipped maps carry them commented out (opt-in: a bench
controller without those addresses would refuse the read); uncommented they
name the simulated controllers' own addresses, and the plant side reads back
the line the daemon's stand-in wrote."""

from __future__ import annotations

import math
import re
from typing import Any

import pytest

from drivers.sim.drive import DriveLoop, open_drive_driver
from drivers.sim.drive_map import DriveMap, DriveMapError, parse_drive_map
from drivers.sim.programs import constant
from drivers.sim.registry import make_sim_controller
from drivers.temp_comp import AXES, AxisCompensation, write_compensation
from models.nesting import loads_toml
from tests.drivers.test_drive import _daemon, _url, bench
from tests.drivers.test_temp_comp import LINES, assert_line, axis_outputs
from tests.shipped import MAPS

PROTOCOLS = ("opcua", "s7", "modbus")


def opted_in(protocol: str) -> DriveMap:
    """The shipped map with its commented-out per-axis lines taken in."""
    text = (MAPS / f"{protocol}.toml").read_text(encoding="utf-8")
    text, n = re.subn(r"(?m)^# ([xyz]_comp_)", r"\1", text)
    assert n == 9, n
    return parse_drive_map(loads_toml(text))


@pytest.mark.parametrize("protocol", PROTOCOLS)
async def test_shipped_map_names_the_sim_parameters(protocol: str) -> None:
    sim: Any = make_sim_controller(protocol)
    assert not any("_comp_" in n for n in parse_drive_map(
        loads_toml((MAPS / f"{protocol}.toml").read_text(encoding="utf-8"))).read)
    drive_map = opted_in(protocol)
    assert {n: a for n, a in drive_map.read.items() if "_comp_" in n} == sim.temp_comp


def test_unknown_read_name_refused() -> None:
    doc = {"protocol": "modbus",
           "write": {"bearing": {"address": 20, "type": "int16"}},
           "read": {"offset": {"address": 0}, "w_comp_value": {"address": 40}}}
    with pytest.raises(DriveMapError, match=r"read: unknown name\(s\) \['w_comp_value'\]"):
        parse_drive_map(doc)


@pytest.mark.parametrize("protocol", PROTOCOLS)
async def test_the_plant_reads_the_line_the_daemon_wrote(protocol: str) -> None:
    async with bench(protocol) as (sim, _shipped, extra):
        drive_map = opted_in(protocol)
        drive = DriveLoop(open_drive_driver(_url(sim), drive_map, **extra), drive_map,
                          program=constant(9_000.0, 1.0, 1.0), seed=3, speedup=20_000.0)
        daemon = _daemon(sim, drive_map, extra)
        outs = axis_outputs(dict(drive_map.read))
        try:
            await drive.prime()
            assert drive.lines == dict.fromkeys(AXES, AxisCompensation(0.0, 0.0, 0.0))
            await write_compensation(daemon, outs, LINES, also={"offset": 4.0})
            await drive.tick()
        finally:
            await daemon.close()
            await drive.stop()
            await drive.driver.close()
        assert drive.latest["offset_um"] == pytest.approx(4.0, abs=1e-6)
        for axis in AXES:
            assert_line(drive.lines[axis], LINES[axis])
            held = await sim.compensation(axis)
            assert math.isclose(held.at(600.0), LINES[axis].at(600.0), abs_tol=2e-3)
