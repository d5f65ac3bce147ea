"""One name per thing, with the former names still taken for a while: the
simulators' ``speed_rpm`` is ``spindle_rpm`` and the shop machine's ``t01_degC``
is ``t1_degC`` (the real record's names); `compd replay --probe-every SECONDS`
is ``--probe-every-min MINUTES`` as in `compd sim` and `compd plan`. A record,
model, drive map, config or command line that uses a former name still works
and says once, in one line, which name to use."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

from compd.cli import main
from compd.offline.records import read_record
from drivers.sim import CHANNELS, renamed
from drivers.sim.csvlog import RECORD_COLUMNS
from drivers.sim.drive_map import MAPS_DIR, parse_drive_map
from drivers.sim.shop import SHOP_COLUMNS
from tests.compd.offline.records_gen import make_record
from tests.shipped import EXAMPLES

REAL = Path(__file__).resolve().parents[2] / "data" / "fl_thermal" / "calibration.csv"


@pytest.fixture(autouse=True)
def _fresh_warnings(monkeypatch: pytest.MonkeyPatch) -> None:
    """Each test its own "once per process"."""
    monkeypatch.setattr(renamed, "_warned", set())


def _warnings(err: str) -> list[str]:
    return [line for line in err.splitlines() if "former name" in line]


def test_the_simulators_use_the_real_records_names() -> None:
    header = REAL.read_text().splitlines()[0].split(",")
    assert set(SHOP_COLUMNS) - {"dz_um"} <= set(header)
    assert "spindle_rpm" in CHANNELS and "spindle_rpm" in RECORD_COLUMNS
    assert not set(renamed.FORMER_NAMES) & {*CHANNELS, *RECORD_COLUMNS, *SHOP_COLUMNS}


@pytest.mark.parametrize("example", sorted(p.name for p in EXAMPLES.glob("*.toml")))
def test_the_shipped_examples_use_the_current_names(example: str) -> None:
    text = (EXAMPLES / example).read_text()
    doc = tomllib.loads(text)
    assert "spindle_rpm" in doc["channels"]
    assert not any(old in text for old in renamed.FORMER_NAMES)


def _old_record(path: Path, n: int = 200) -> Path:
    t = np.arange(n) * 60.0
    temp = 20.0 + np.minimum(t / 3600.0, 3.0)
    rows = [f"{a:g},{9000 if a < 6000 else 0},{b:.2f},{2.0 * (b - 20.0):.3f}"
            for a, b in zip(t, temp, strict=True)]
    path.write_text("time_s,speed_rpm,t01_degC,dz_um\n" + "\n".join(rows) + "\n")
    return path


def test_an_old_record_is_read_with_the_current_names_and_says_so_once(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    first = read_record(_old_record(tmp_path / "a.csv"))
    first.require(["spindle_rpm", "t1_degC"])
    assert first.column("spindle_rpm")[0] == 9000.0 and first.column("t1_degC")[0] == 20.0
    assert "speed_rpm" not in first.columns
    lines = _warnings(capsys.readouterr().err)
    assert len(lines) == 2
    assert any("'speed_rpm'" in ln and "use 'spindle_rpm'" in ln for ln in lines)
    assert any("'t01_degC'" in ln and "use 't1_degC'" in ln for ln in lines)
    second = read_record(_old_record(tmp_path / "b.csv"))
    second.require(["spindle_rpm", "t1_degC"])
    assert capsys.readouterr().err == ""  # once per process


def test_old_names_on_the_command_line_and_in_a_model_meet_a_new_record(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`compd fit --term t01_degC` on a record with t1_degC, and the model it wrote
    (its term on t01_degC) replayed on that record."""
    old = _old_record(tmp_path / "old.csv")
    new = tmp_path / "new.csv"
    new.write_text(old.read_text().replace("speed_rpm,t01_degC", "spindle_rpm,t1_degC", 1))
    model = tmp_path / "m.toml"
    assert main(["fit", str(new), "--column", "dz_um", "--term", "t01_degC", "--orders",
                 "1-1", "-o", str(model)]) == 0
    err = capsys.readouterr().err
    assert len(_warnings(err)) == 1 and "use 't1_degC'" in err
    assert main(["replay", str(model), str(new), "--column", "dz_um", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["fit_percent"] > 90.0
    # the current name on the old record: the same model, the same figures
    assert main(["fit", str(old), "--column", "dz_um", "--term", "t1_degC", "--orders",
                 "1-1", "-o", str(tmp_path / "m2.toml")]) == 0


def test_a_drive_map_with_the_former_channel_name_loads(
        capsys: pytest.CaptureFixture[str]) -> None:
    doc = tomllib.loads((MAPS_DIR / "modbus.toml").read_text())
    doc["write"]["speed_rpm"] = doc["write"].pop("spindle_rpm")
    drive_map = parse_drive_map(doc, "old-bench.toml")
    assert "spindle_rpm" in drive_map.write and "speed_rpm" not in drive_map.write
    lines = _warnings(capsys.readouterr().err)
    assert len(lines) == 1 and lines[0].startswith("compd: warning: old-bench.toml: [write]")


async def test_the_opcua_sim_serves_the_former_node_too(
        capsys: pytest.CaptureFixture[str]) -> None:
    """A config written before the rename (``ns=2;s=Machine.speed_rpm``) still reads
    the spindle speed; the sim says once to use the current node."""
    from drivers.addresses import OpcUaAddress
    from drivers.backoff import Backoff
    from drivers.opcua import OpcUaDriver
    from drivers.sim.opcua_server import OpcUaSimController, node_id

    async with OpcUaSimController() as sim:
        await sim.publish({"spindle_rpm": 8000.0})
        current = sim.channels["spindle_rpm"]
        assert isinstance(current, OpcUaAddress)
        driver = OpcUaDriver(sim.endpoint, {"speed_rpm": OpcUaAddress(node=node_id("speed_rpm")),
                                            "spindle_rpm": current},
                             {}, timeout_s=2.0, backoff=Backoff(initial_s=0.02, cap_s=0.1))
        try:
            await driver.connect()
            for _ in range(2):
                got = await driver.read(["speed_rpm", "spindle_rpm"])
                assert got["speed_rpm"].value == got["spindle_rpm"].value == 8000.0
        finally:
            await driver.close()
    lines = _warnings(capsys.readouterr().err)
    assert len(lines) == 1 and "Machine.speed_rpm" in lines[0] and "'spindle_rpm'" in lines[0]


def test_replay_probe_every_seconds_is_probe_every_min_with_one_warning(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    data = tmp_path / "r.csv"
    make_record(data, "sp2", hours=3.0, seed=4)
    base = ["replay", "sp2", str(data), "--column", "dz_um", "--json"]
    assert main([*base, "--probe-every-min", "30"]) == 0
    new = capsys.readouterr()
    assert main([*base, "--probe-every", "1800"]) == 0
    old = capsys.readouterr()
    assert json.loads(old.out) == json.loads(new.out)
    assert new.err == ""
    assert old.err.count("\n") == 1
    assert "--probe-every 1800 is --probe-every-min 30" in old.err


@pytest.mark.parametrize("command", [["replay", "sp2", "r.csv"], ["sim"], ["plan"]])
def test_every_probe_option_is_in_minutes_and_says_so(
        command: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main([command[0], "--help"])
    assert exc.value.code == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "--probe-every-min MINUTES" in out and "minutes" in out


def test_demo_takes_a_model_on_the_former_channel_name(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`compd demo --model` with a term on speed_rpm: the config reads the spindle speed
    under the model's name, once, from the simulated machine's spindle_rpm."""
    from compd.offline.demo import daemon_config
    from drivers.sim.modbus_server import ModbusSimController
    from tests.shipped import LIBRARY

    text = (LIBRARY / "sp2.toml").read_text()
    model = tmp_path / "old.toml"
    model.write_text(text.replace('channels = ["bearing", "ambient"]',
                                  'channels = ["bearing", "speed_rpm"]')
                     .replace("inputs = { ambient = 1.0 }", "inputs = { speed_rpm = 1.0 }"))
    sim = ModbusSimController()
    doc = daemon_config(sim, model=str(model), period_s=1.0, time_scale=1.0,
                        state_dir=tmp_path / "state")
    assert set(doc["channels"]) == {"bearing", "speed_rpm"}
    assert doc["channels"]["speed_rpm"]["address"] == sim.channels["spindle_rpm"].model_dump()
    assert doc["channels"]["speed_rpm"]["unit"] == "rpm"
    lines = _warnings(capsys.readouterr().err)
    assert len(lines) == 1 and "use 'spindle_rpm'" in lines[0]
