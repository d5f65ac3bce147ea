"""`compd sim --drive URL`: the HIL bench's machine side as a command, against
the simulated controllers (the same code path a bench uses): as a real
subprocess, in-process through `main`, with the daemon (`compd run`) closing
the loop, and its usage / map errors. Also: the shipped daemon-side bench
configs agree with the drive maps."""

from __future__ import annotations

import asyncio
import json
import math
import re
import signal
import sys
from pathlib import Path
from typing import Any

import pytest

from compd.cli import main
from compd.config.loader import load_config
from drivers.modbus_codec import decode
from drivers.sim.drive import RECORD_FIELDS
from drivers.sim.drive_map import load_drive_map
from drivers.sim.registry import make_sim_controller
from tests.record_columns import read_columns as read_record
from tests.shipped import MAPS

REPO = Path(__file__).resolve().parents[3]
HIL = REPO / "deploy" / "hil"
PROTOCOLS = ("modbus", "s7", "focas", "opcua")


async def _compd(tmp_path: Path, *args: str, name: str = "compd") -> asyncio.subprocess.Process:
    with (tmp_path / f"{name}.stderr").open("wb") as stderr:
        return await asyncio.create_subprocess_exec(
            sys.executable, "-m", "compd", *args, cwd=REPO,
            stdout=asyncio.subprocess.PIPE, stderr=stderr)


async def test_subprocess_drives_a_modbus_controller(tmp_path: Path) -> None:
    sim: Any = make_sim_controller("modbus")
    await sim.start()
    drive_map = load_drive_map(MAPS / "modbus.toml")
    try:
        await sim.publish({"offset": 5.0, "heartbeat": 99, "status": 1})  # the daemon's part
        out = tmp_path / "run.csv"
        proc = await _compd(tmp_path, "sim", "--drive", sim.endpoint, "--speedup", "5000",
                            "--duration-h", "0.05", "--program", "constant", "--record",
                            str(out), "--print-every-s", "0")
        stdout, _ = await asyncio.wait_for(proc.communicate(), 60.0)
        text = stdout.decode()
        assert proc.returncode == 0, (tmp_path / "compd.stderr").read_text()
        assert "wrote 181 rows" in text and "0 link error(s)" in text
        assert "heartbeat=99" in text and "offset=5.00 um" in text

        rec = read_record(out)
        assert list(rec) == list(RECORD_FIELDS)
        assert set(rec["offset_um"]) == {5.0} and set(rec["heartbeat"]) == {99.0}
        assert rec["error_um"] == pytest.approx(rec["dz_um"] - 5.0, abs=2e-3)
        # the controller's holding registers hold the plant's last row
        for name in ("bearing", "motor", "column", "table", "ambient", "spindle_rpm"):
            addr: Any = drive_map.write[name]
            raw = decode(addr, sim.raw("holding", addr.address, addr.count))
            assert raw == pytest.approx(rec[name][-1], abs=1e-6), name
        assert sim.raw("holding", 25, 1) == [9_000]
        # ... and the outputs the daemon wrote are untouched
        assert await sim.outputs() == {"offset": 5.0, "heartbeat": 99.0, "status": 1.0}
    finally:
        await sim.stop()


def test_in_process_drives_an_s7_cpu(tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                     ) -> None:
    sim: Any = make_sim_controller("s7")  # a threaded server: no event loop needed
    asyncio.run(sim.start())
    try:
        asyncio.run(sim.publish({"offset": -2.5, "heartbeat": 3}))
        out = tmp_path / "s7.csv"
        rc = main(["sim", "--drive", sim.endpoint, "--map", str(MAPS / "s7.toml"),
                   "--speedup", "10000", "--duration-h", "0.02", "--record", str(out),
                   "--program", "constant", "--print-every-s", "0"])
        assert rc == 0, capsys.readouterr().err
        rec = read_record(out)
        assert len(rec["time_s"]) == 73
        assert set(rec["offset_um"]) == {-2.5}
        assert rec["error_um"] == pytest.approx(rec["dz_um"] + 2.5, abs=2e-3)
        assert asyncio.run(sim.read_back("bearing")) == pytest.approx(rec["bearing"][-1])
        assert asyncio.run(sim.read_back("spindle_rpm")) == 9_000.0
    finally:
        asyncio.run(sim.stop())


async def _loop_closed(drive: Any, daemon: asyncio.subprocess.Process, beats: int,
                       limit_s: float = 120.0) -> None:
    """Until the daemon's heartbeat, read back by the drive loop, has advanced
    `beats` times and the last row shows the loop closed (status OK, a positive
    offset); polled, bounded only by a generous limit: a loaded machine (the
    daemon's process slow to start) makes this slower, never red."""
    seen: list[float] = []
    for _ in range(int(limit_s / 0.01)):
        row = drive.latest
        beat = row.get("heartbeat", math.nan)
        if math.isfinite(beat) and beat > 0 and (not seen or beat != seen[-1]):
            seen.append(beat)
        if (len(seen) > beats and int(row["status"]) & 1  # Status.OK
                and row["offset_um"] > 0.0):
            return
        if daemon.returncode is not None:
            raise AssertionError(f"compd run ended ({daemon.returncode}) early")
        await asyncio.sleep(0.01)
    raise AssertionError(f"the loop never closed: heartbeats seen {seen[-5:]}, "
                         f"last row {drive.latest}")


async def test_the_daemon_closes_the_loop_through_the_controller(tmp_path: Path) -> None:
    """`compd sim --no-plant` (the stand-in PLC), `compd run` on the bench
    config, and the drive loop: the daemon's offset reaches the plant and its
    heartbeat advances."""
    from drivers.sim.drive import DriveLoop, open_drive_driver
    from drivers.sim.programs import constant

    sim: Any = make_sim_controller("modbus")
    await sim.start()
    text = (HIL / "modbus.toml").read_text()
    text = text.replace("modbus://127.0.0.1:15020", sim.endpoint)
    text = text.replace('dir = "/tmp/compd-hil-modbus"', f'dir = "{tmp_path / "state"}"')
    # the bench config as shipped (60x, a real period of 1 s, a 0.4 s request
    # timeout): a late answer on a loaded machine holds a cycle, it does not break
    # the loop
    config = tmp_path / "modbus.toml"
    config.write_text(text)
    drive_map = load_drive_map(MAPS / "modbus.toml")
    drive = DriveLoop(open_drive_driver(sim.endpoint, drive_map), drive_map,
                      program=constant(9_000.0, 1.0, 1.0), speedup=10.0, record=True)
    daemon = await _compd(tmp_path, "run", str(config), name="run")
    try:
        drive.start()
        await _loop_closed(drive, daemon, beats=3)
    finally:
        await drive.stop()
        if daemon.returncode is None:
            daemon.send_signal(signal.SIGTERM)
        rc = await asyncio.wait_for(daemon.wait(), 60.0)
        await sim.stop()
    assert rc == 0, (tmp_path / "run.stderr").read_text()
    rows = drive.history
    assert rows[-1]["offset_um"] > 0.0  # the spindle heats: the model asks for a positive offset
    assert all(r["error_um"] == pytest.approx(r["growth_um"] - r["offset_um"]) for r in rows)
    assert drive.link_errors == 0


@pytest.mark.parametrize("protocol", PROTOCOLS)
def test_bench_configs_read_where_the_maps_write(protocol: str) -> None:
    config = load_config(HIL / f"{protocol}.toml")
    drive_map = load_drive_map(MAPS / f"{protocol}.toml")
    assert config.raw.controller.protocol == drive_map.protocol == protocol
    for name, addr in config.channels.items():
        assert drive_map.write[name] == addr, name
    for name, addr in config.outputs.items():
        assert drive_map.read[name] == addr, name
    # the daemon writes µm (after the address's own scale); the plant reads µm
    assert config.raw.output.unit == "um" and drive_map.offset_um_per_unit == 1.0


@pytest.mark.parametrize(("argv", "rc", "message"), [
    (["--drive", "modbus://127.0.0.1:1", "--protocol", "modbus"], 64, "drop --protocol"),
    (["--drive", "modbus://127.0.0.1:1", "--json"], 64, "do not apply"),
    (["--drive", "http://x:1"], 64, "unknown protocol"),
    (["--drive", "modbus://127.0.0.1:1", "--duration-h", "-1"], 64, "--duration-h"),
    (["--drive", "s7://127.0.0.1:1", "--focas-library", "/x.so"], 64, "focas:// only"),
    (["--map", "m.toml", "--protocol", "modbus"], 64, "apply to --drive only"),
    (["--drive", "s7://127.0.0.1:1", "--map", str(MAPS / "modbus.toml")], 78,
     "drive map is for modbus"),
    (["--drive", "s7://127.0.0.1:1", "--map", "/nonexistent.toml"], 66, "cannot read"),
    (["--drive", "focas://127.0.0.1:8193", "--focas-library", "/nonexistent/libfwlib32.so"],
     78, "not a file"),
])
def test_usage_and_map_errors(argv: list[str], rc: int, message: str,
                              capsys: pytest.CaptureFixture[str]) -> None:
    try:
        got = main(["sim", *argv])
    except SystemExit as exc:  # refused by the parser
        got = int(str(exc.code))
    assert got == rc
    assert message in capsys.readouterr().err


def test_unreachable_controller_keeps_the_plant_running(capsys: pytest.CaptureFixture[str]
                                                        ) -> None:
    from drivers.sim.ports import free_tcp_port

    port = free_tcp_port()  # nobody listens there
    rc = main(["sim", "--drive", f"modbus://127.0.0.1:{port}", "--speedup", "10000",
               "--duration-h", "0.005", "--print-every-s", "0"])
    out = capsys.readouterr().out
    assert rc == 0
    assert "stopped after 0.005 h" in out and "link=DOWN" in out
    assert not re.search(r" 0 link error", out)


async def test_no_plant_serves_a_stand_in_plc_for_the_drive(tmp_path: Path) -> None:
    """`compd sim --protocol modbus --no-plant --json`: nothing publishes into
    the controller; `--drive` (here in-process) fills it."""
    from drivers.factory import open_driver
    from drivers.sim.drive import DriveLoop, open_drive_driver

    proc = await _compd(tmp_path, "sim", "--protocol", "modbus", "--no-plant", "--json",
                        name="plc")
    try:
        assert proc.stdout is not None
        line = await asyncio.wait_for(proc.stdout.readline(), 30.0)
        assert line, (tmp_path / "plc.stderr").read_text()
        endpoint = json.loads(line)["endpoint"]
        drive_map = load_drive_map(MAPS / "modbus.toml")
        probe = open_driver("modbus", endpoint, drive_map.write, {})
        try:
            idle = await probe.read(["bearing", "spindle_rpm"])
            assert idle["bearing"].value == 0.0 and idle["spindle_rpm"].value == 0.0  # no plant
            drive = DriveLoop(open_drive_driver(endpoint, drive_map), drive_map,
                              speedup=10_000.0)
            await drive.run(until_s=20.0)
            assert drive.link_errors == 0
            got = await probe.read(["bearing", "spindle_rpm"])
            assert got["bearing"].value == pytest.approx(drive.latest["bearing"], abs=0.051)
            assert got["spindle_rpm"].value == drive.latest["spindle_rpm"] > 0.0
        finally:
            await probe.close()
    finally:
        if proc.returncode is None:
            proc.send_signal(signal.SIGTERM)
        await asyncio.wait_for(proc.wait(), 20.0)
    assert proc.returncode == 0
