"""A record through the daemon's own cycle (`compd.offline.cycle_replay`): the
model output is the bare replay's, the offset is what the output stage lets
through (slew limit, hold on a bad row)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from compd.infiles import load_model
from compd.offline.cycle_replay import replay_cycle, replay_params
from compd.offline.model_replay import replay_model
from compd.offline.records import Record
from tests.compd.offline.records_gen import inputs


def _record(hours: float = 2.0) -> Record:
    n = int(hours * 3600)
    cols = inputs(n, seed=3)
    return Record(path="<gen>", sha256="", time_s=cols["time_s"], period_s=1.0,
                  columns={"bearing": np.round(cols["bearing"], 1),
                           "ambient": np.round(cols["ambient"], 1)})


def test_a_generous_output_stage_writes_the_bare_models_output() -> None:
    record = _record()
    bare = replay_model(load_model("sp2"), record)
    model = load_model("sp2")
    out = replay_cycle(replay_params(model, limit_um=1000.0, slew_um_s=1000.0), model, record)
    assert np.array_equal(out.model_um, bare)  # stepped exactly as the bare replay
    assert np.max(np.abs(out.offset_um - bare)) <= 1e-9
    assert out.in_force.all() and set(out.states) == {"ok"}


def test_the_slew_limit_holds_on_every_row() -> None:
    record = _record()
    model = load_model("sp2")
    slew = 0.002  # µm/s: slower than the model moves while the spindle heats
    out = replay_cycle(replay_params(model, limit_um=1000.0, slew_um_s=slew), model, record)
    steps = np.abs(np.diff(out.offset_um))
    assert steps.max() <= slew * record.period_s + 1e-12
    assert np.max(np.abs(out.offset_um - out.model_um)) > 1.0  # it lagged the model


def test_a_bad_row_holds_the_offset_and_leaves_the_model_unstepped() -> None:
    record = _record(0.5)
    bearing = record.columns["bearing"].copy()
    bearing[600] = math.nan
    record = Record(path=record.path, sha256="", time_s=record.time_s, period_s=1.0,
                    columns={**record.columns, "bearing": bearing})
    model = load_model("sp2")
    out = replay_cycle(replay_params(model, limit_um=1000.0, slew_um_s=1000.0), model, record)
    assert out.states[600] == "hold" and not out.in_force[600]
    assert math.isnan(out.model_um[600])
    assert out.offset_um[600] == out.offset_um[599]
    assert out.states[601] == "ok"


def test_a_record_without_a_model_channel_is_refused() -> None:
    from compd.offline.records import RecordError

    record = _record(0.1)
    record = Record(path="<gen>", sha256="", time_s=record.time_s, period_s=1.0,
                    columns={"bearing": record.columns["bearing"]})
    model = load_model("sp2")
    with pytest.raises(RecordError, match="ambient"):
        replay_cycle(replay_params(model, limit_um=100.0, slew_um_s=1.0), model, record)


# -- `compd replay --config`: the command line through the cycle ----------------------------

def _csv_and_config(tmp_path: Path, *, slew_um_s: float, spike_at: int | None = None
                    ) -> tuple[Path, Path]:
    import csv

    from tests.configs import write_config

    record = _record(1.0)
    bare = replay_model(load_model("sp2"), record)
    bearing = record.columns["bearing"].copy()
    if spike_at is not None:
        bearing[spike_at] = 200.0  # beyond the config's range for the bearing (-20 … 150)
    data = tmp_path / "run.csv"
    with data.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["time_s", "bearing", "ambient", "dz_um"])
        for k in range(len(record)):
            w.writerow([f"{record.time_s[k]:g}", f"{bearing[k]:.1f}",
                        f"{record.columns['ambient'][k]:.1f}", f"{bare[k]:.6f}"])
    config = write_config(tmp_path, "modbus://127.0.0.1:1502", time_scale=1.0,
                          slew_um_s=slew_um_s)
    # sp2 reaches 123 µm in this hour: a limit above it (the clamp is the slew test's)
    config.write_text(config.read_text().replace("limit_um = 100.0", "limit_um = 1000.0"))
    return data, config


def _replay_json(argv: list[str], capsys: pytest.CaptureFixture[str]) -> dict[str, Any]:
    import json

    from compd.cli import main

    assert main(argv) == 0
    out: dict[str, Any] = json.loads(capsys.readouterr().out.splitlines()[-1])
    return out


def test_replay_through_the_cycle_is_the_bare_model_under_a_generous_output_stage(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    data, config = _csv_and_config(tmp_path, slew_um_s=100.0)
    cyc = _replay_json(["replay", "sp2", str(data), "--column", "dz_um", "--config",
                        str(config), "--json"], capsys)
    assert cyc["through"] == "cycle" and cyc["init"] == "daemon"
    assert float(cyc["fit_percent"]) > 99.0


def test_replay_through_the_cycle_lags_by_the_slew_limit(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    data, config = _csv_and_config(tmp_path, slew_um_s=0.001)  # 3.6 µm in the hour
    cyc = _replay_json(["replay", "sp2", str(data), "--column", "dz_um", "--config",
                        str(config), "--json"], capsys)
    assert float(cyc["fit_percent"]) < 20.0


def test_replay_through_the_cycle_refuses_a_row_the_daemon_refuses(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A 200 °C bearing row (the config's range ends at 150): the bare model takes it into
    its filters and carries the error on; the daemon holds its offset for that row."""
    data, config = _csv_and_config(tmp_path, slew_um_s=100.0, spike_at=1200)
    bare = _replay_json(["replay", "sp2", str(data), "--column", "dz_um", "--init", "rest",
                         "--json"], capsys)
    cyc = _replay_json(["replay", "sp2", str(data), "--column", "dz_um", "--config",
                        str(config), "--json"], capsys)
    assert bare["through"] == "model"
    assert float(cyc["rms_um"]) < 0.1 * float(bare["rms_um"])


@pytest.mark.parametrize(("extra", "words"), [
    (["--init", "rest"], "--init goes without --config"),
    (["--probe-every-min", "60"], "--probe-every-min goes without --config"),
])
def test_replay_config_usage_errors_are_one_line(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str],
                                                 extra: list[str], words: str) -> None:
    from compd.cli import main

    data, config = _csv_and_config(tmp_path, slew_um_s=1.0)
    assert main(["replay", "sp2", str(data), "--column", "dz_um", "--config", str(config),
                 *extra]) == 64
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1


def test_replay_with_a_bad_config_is_78_and_one_line(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]
                                                     ) -> None:
    from compd.cli import main

    data, config = _csv_and_config(tmp_path, slew_um_s=1.0)
    config.write_text(config.read_text().replace("limit_um = 1000.0", "limit_um = -1.0"))
    assert main(["replay", "sp2", str(data), "--column", "dz_um", "--config",
                 str(config)]) == 78
    err = capsys.readouterr().err
    assert "limit_um" in err and err.count("\n") == 1


def test_replay_of_a_model_the_config_has_no_channel_for_is_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """MODEL is checked against CONFIG's channels by the loader's own check, as the
    config's model is: a model reading a channel the config lacks (``table``) is one
    line naming it and EX_DATAERR, never a KeyError from the cycle."""
    import csv

    from compd.cli import main
    from tests.configs import write_config

    record = _record(0.1)
    data = tmp_path / "lathe.csv"
    with data.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["time_s", "bearing", "column", "table", "clamp_gain", "ambient", "dz_um"])
        for k in range(len(record)):
            b = f"{record.columns['bearing'][k]:.1f}"
            w.writerow([f"{record.time_s[k]:g}", b, "20.0", b, "1.0", "20.0", f"{k % 7}"])
    config = write_config(tmp_path, "modbus://127.0.0.1:1502", time_scale=1.0)
    config.write_text(config.read_text().replace("[model]", (  # every channel but table
        '[channels.column]\naddress = { kind = "input", address = 2, type = "int16", '
        'scale = 0.1 }\nunit = "degC"\nrange = [-20.0, 150.0]\n\n'
        '[channels.clamp_gain]\naddress = { kind = "input", address = 6, type = "float32" }'
        '\nunit = "ratio"\nrange = [0.0, 10.0]\n\n[model]')))
    capsys.readouterr()
    rc = main(["replay", "lathe_milling_turning", str(data), "--column", "dz_um",
               "--config", str(config)])
    err = capsys.readouterr().err
    assert rc == 65, err
    assert "'table'" in err and str(config) in err and err.count("\n") == 1
    assert "Traceback" not in err
