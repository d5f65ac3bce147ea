"""`compd sim`: the --json first line of a served machine (in a real
subprocess, against whichever simulated controllers exist) and --record
offline."""

from __future__ import annotations

import asyncio
import importlib.util
import json
import signal
import sys
from pathlib import Path
from typing import Any

import pytest

from compd.cli import main
from drivers.addresses import ADDRESS_TYPES, Address
from drivers.factory import DRIVERS, open_driver
from drivers.sim import AXIS_OUTPUTS, CHANNELS, OUTPUTS
from drivers.sim.csvlog import RECORD_COLUMNS
from drivers.sim.registry import SIM_CONTROLLERS
from tests.record_columns import read_columns as read_record

REPO = Path(__file__).resolve().parents[3]


def _sim_exists(protocol: str) -> bool:
    return importlib.util.find_spec(SIM_CONTROLLERS[protocol][0]) is not None


def _driver_exists(protocol: str) -> bool:
    return importlib.util.find_spec(DRIVERS[protocol][0]) is not None


def _address(protocol: str, dumped: dict[str, Any]) -> Address:
    """The one address model of `protocol` that round-trips `dumped`."""
    for model in ADDRESS_TYPES[protocol]:
        try:
            addr: Address = model.model_validate(dumped)
        except ValueError:
            continue
        if addr.model_dump() == dumped:
            return addr
    raise AssertionError(f"{dumped} is not a {protocol} address")


async def _start(tmp_path: Path, *args: str) -> asyncio.subprocess.Process:
    stderr = (tmp_path / "stderr.txt").open("wb")
    try:
        return await asyncio.create_subprocess_exec(
            sys.executable, "-m", "compd", "sim", *args, cwd=REPO,
            stdout=asyncio.subprocess.PIPE, stderr=stderr)
    finally:
        stderr.close()


async def _finish(proc: asyncio.subprocess.Process, sig: signal.Signals) -> int:
    if proc.returncode is None:
        proc.send_signal(sig)
        try:
            await asyncio.wait_for(proc.wait(), 20.0)
        except TimeoutError:
            proc.kill()
            await proc.wait()
            raise
    assert proc.returncode is not None
    return proc.returncode


#: each axis's position (mm) and plain offset (µm) as ``--json`` lists them, per protocol
#: that has them: Modbus input 16–21 and holding 50–55 (float32), FOCAS PMC D300–D308
#: (float) and D320–D328 (long, 0.1 µm)
POSITIONS: dict[str, dict[str, Any]] = {
    "modbus": {f"{a}_position": {"unit": 1, "kind": "input", "address": 16 + 2 * i,
                                 "type": "float32", "word_order": "big", "scale": 1.0}
               for i, a in enumerate("xyz")},
    "focas": {f"{a}_position": {"kind": "pmc", "area": "D", "address": 300 + 4 * i,
                                "type": "float", "scale": 1.0} for i, a in enumerate("xyz")}}
AXIS_OFFSETS: dict[str, dict[str, Any]] = {
    "modbus": {f"{a}_comp_offset": {"unit": 1, "kind": "holding", "address": 50 + 2 * i,
                                    "type": "float32", "word_order": "big", "scale": 1.0}
               for i, a in enumerate("xyz")},
    "focas": {f"{a}_comp_offset": {"kind": "pmc", "area": "D", "address": 320 + 4 * i,
                                   "type": "long", "scale": 0.1} for i, a in enumerate("xyz")}}


@pytest.mark.parametrize("protocol", list(SIM_CONTROLLERS))
async def test_json_first_line_describes_a_live_machine(protocol: str, tmp_path: Path) -> None:
    if not _sim_exists(protocol):
        pytest.skip(f"{SIM_CONTROLLERS[protocol][0]} does not exist yet")
    if protocol == "linuxcnc":
        pytest.skip("a real LinuxCNC on this machine, not a server on 127.0.0.1 (one per "
                    "machine): tests/compd/runtime/test_e2e_linuxcnc.py")
    proc = await _start(tmp_path, "--protocol", protocol, "--json", "--speedup", "600",
                        "--program", "constant", "--seed", "4")
    try:
        assert proc.stdout is not None
        line = await asyncio.wait_for(proc.stdout.readline(), 30.0)
        assert line, (tmp_path / "stderr.txt").read_text()
        info = json.loads(line)
        assert set(info) - {"focas", "temp_comp", "positions", "axis_offsets",
                            "tool_comp"} == {"protocol", "endpoint", "channels", "outputs",
                                             "probes"}
        # the per-axis compensation parameters where the controller has them
        assert set(info.get("temp_comp", AXIS_OUTPUTS)) == set(AXIS_OUTPUTS)
        assert ("temp_comp" in info) == (protocol in ("opcua", "s7", "modbus"))
        # each axis's position and plain offset (an offset written at the position read)
        # and the SINUMERIK tool direction, where the controller has them
        assert info.get("positions") == POSITIONS.get(protocol)
        assert info.get("axis_offsets") == AXIS_OFFSETS.get(protocol)
        assert set(info.get("tool_comp", ())) == (
            {"tool_comp_value"} if protocol in ("opcua", "s7") else set())
        if protocol == "opcua":
            assert info["tool_comp"]["tool_comp_value"]["node"] == \
                "ns=2;s=Machine.Channel.$SC_TOOL_TEMP_COMP"
        if protocol == "s7":
            assert (info["tool_comp"]["tool_comp_value"]["db"],
                    info["tool_comp"]["tool_comp_value"]["offset"]) == (13, 0)
        assert info["protocol"] == protocol
        assert "127.0.0.1" in info["endpoint"]
        assert set(CHANNELS) <= set(info["channels"])
        assert set(OUTPUTS) <= set(info["outputs"])
        channels = {n: _address(protocol, a) for n, a in info["channels"].items()}
        outputs = {n: _address(protocol, a) for n, a in info["outputs"].items()}

        if _driver_exists(protocol):  # and it really serves the plant
            options: dict[str, Any] = {}
            if protocol == "focas":  # the stand-in library the sim process built (same cache)
                from drivers.sim.fwlib_build import build_standin
                options["library_path"] = str(build_standin())
            driver = open_driver(protocol, info["endpoint"], channels, outputs, timeout_s=2.0,
                                 **options)
            try:
                await driver.connect()
                got = await driver.read(["bearing", "ambient", "spindle_rpm"])
                assert 10.0 < got["bearing"].value < 60.0
                assert 10.0 < got["ambient"].value < 30.0
                assert got["spindle_rpm"].value in (0.0, 9_000.0)
            finally:
                await driver.close()
    finally:
        rc = await _finish(proc, signal.SIGTERM)
    assert rc == 0, (tmp_path / "stderr.txt").read_text()


@pytest.mark.skipif(not _sim_exists("modbus"), reason="drivers/sim/modbus_server.py missing")
async def test_text_mode_lists_addresses_and_stops_on_sigint(tmp_path: Path) -> None:
    proc = await _start(tmp_path, "--protocol", "modbus")
    try:
        assert proc.stdout is not None
        head = [await asyncio.wait_for(proc.stdout.readline(), 30.0) for _ in range(3)]
        assert b"modbus://127.0.0.1:" in head[0]
        assert b"program spectrum" in head[1]
    finally:
        rc = await _finish(proc, signal.SIGINT)
    rest = (await proc.stdout.read()).decode()
    assert rc == 0
    assert "bearing" in rest and "offset" in rest and "stopped after" in rest


def test_record_writes_a_calibration_csv(tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                         ) -> None:
    out = tmp_path / "cal.csv"
    rc = main(["sim", "--record", str(out), "--program", "constant", "--hours", "1",
               "--period-s", "10", "--seed", "2"])
    assert rc == 0
    assert "wrote 361 rows" in capsys.readouterr().out
    assert out.read_text().splitlines()[0] == ",".join(RECORD_COLUMNS)
    rec = read_record(out)
    assert len(rec["time_s"]) == 361 and rec["time_s"][-1] == 3600.0
    assert set(rec["spindle_rpm"][1:]) == {9_000.0, 0.0}
    assert rec["dz_um"].max() > 10.0


def test_record_defaults_to_the_spectrum_at_one_second(tmp_path: Path) -> None:
    out = tmp_path / "spec.csv"
    assert main(["sim", "--record", str(out), "--hours", "0.25", "--probe-noise-um", "0"]) == 0
    rec = read_record(out)
    assert len(rec["time_s"]) == 901
    assert rec["spindle_rpm"][1] >= 500.0


@pytest.mark.parametrize("machine", [[], ["--machine", "shop"], ["--machine", "ballscrew"]])
def test_a_record_too_long_is_refused_in_hours_and_rows(
        machine: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "long.csv"
    rc = main(["sim", "--record", str(out), "--hours", "8000", "--period-s", "0.001",
               *machine])
    assert rc == 65
    err = capsys.readouterr().err
    assert err == "compd sim: 8000 h every 0.001 s is 2.88e+10 rows; at most 10,000,000\n"
    assert not out.exists()


@pytest.mark.parametrize("argv", [["sim"], ["sim", "--record", "x.csv", "--protocol", "s7"],
                                  ["sim", "--record", "x.csv", "--probe-noise-um", "-1"]])
def test_usage_errors_exit_64(argv: list[str], tmp_path: Path,
                              capsys: pytest.CaptureFixture[str]) -> None:
    argv = [str(tmp_path / a) if a.endswith(".csv") else a for a in argv]
    try:
        rc = main(argv)
    except SystemExit as exc:  # refused by the parser
        rc = int(str(exc.code))
    assert rc == 64
    assert "compd sim:" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("bad", [["--speedup", "0"], ["--period-s", "-1"], ["--program", "x"],
                                 ["--protocol", "profibus"]])
def test_bad_values_are_refused_by_the_parser(bad: list[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["sim", *bad])
    assert exc.value.code == 64
