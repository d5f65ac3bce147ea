"""What `compd export` writes, `fit`, `replay` and `refine` read.

An export CSV is read as the recorder database it came from reads: the same
channels, on the same machine-seconds clock (``mono_s`` by ``cycle``, never
the wall-clock ``time``), its text columns (``time``, ``state``) and flags
(``valid``, ``valid.<channel>``) not taken for channels.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from compd.cli import main
from compd.offline.records import RecordError, read_record
from compd.runtime.recorder import Recorder, RecordRow

T0 = 1_795_000_000.0
PERIOD_S = 60.0
TIME_SCALE = 60.0  # a cycle a real second: the wall clock and machine seconds differ


def _plant(n: int) -> dict[str, np.ndarray]:
    """A first-order machine: dz follows 3 µm/K of bearing warming, τ 30 min."""
    k = np.arange(n)
    bearing = 20.0 + 8.0 * (np.sin(2 * np.pi * k / 300.0) > 0) + 0.01 * np.sin(k)
    ambient = 20.0 + 0.5 * np.sin(2 * np.pi * k / 1440.0)
    dz = np.zeros(n)
    a = math.exp(-PERIOD_S / 1800.0)
    for i in range(1, n):
        dz[i] = a * dz[i - 1] + (1 - a) * 3.0 * (bearing[i - 1] - 20.0)
    return {"bearing": bearing, "ambient": ambient, "dz_um": dz}


def _recorder(path: Path, n: int) -> Path:
    cols = _plant(n)
    with Recorder(path, commit_every=100) as rec:
        for k in range(n):
            rec.record(RecordRow(
                seq=k + 1, mono_s=1000.0 + PERIOD_S * k + (0.2 if k % 7 == 3 else 0.0),
                wall_s=T0 + PERIOD_S * k / TIME_SCALE, offset_um=None if k == 0 else 0.1 * k,
                model_um=0.05 * k, state="running" if k % 50 else "ok", valid=True,
                channels={name: float(c[k]) for name, c in cols.items()},
                contributions={"bearing": 0.01 * k}))
    return path


def _export(db: Path, out: Path) -> Path:
    assert main(["export", str(db), "-o", str(out)]) == 0
    return out


def test_an_export_reads_as_its_recorder(tmp_path: Path) -> None:
    db = _recorder(tmp_path / "samples.sqlite", 400)
    csv_path = _export(db, tmp_path / "run.csv")
    header = csv_path.read_text(encoding="utf-8").splitlines()[0].split(",")
    assert {"time", "state", "valid", "valid.bearing", "contribution.bearing"} <= set(header)
    from_db, from_csv = read_record(db), read_record(csv_path)
    assert from_csv.period_s == from_db.period_s == PERIOD_S  # machine seconds, not wall
    np.testing.assert_array_equal(from_csv.time_s, from_db.time_s)
    assert sorted(from_csv.columns) == sorted(from_db.columns)
    assert "state" not in from_csv.columns and "offset_um" not in from_csv.columns
    for name, col in from_db.columns.items():
        np.testing.assert_array_equal(from_csv.columns[name], col, err_msg=name)


def test_an_exports_missing_channel_value_is_refused_naming_it(tmp_path: Path) -> None:
    db = tmp_path / "samples.sqlite"
    with Recorder(db, commit_every=10) as rec:
        for k in range(5):
            rec.record(RecordRow(seq=k, mono_s=10.0 * k, wall_s=T0 + k, offset_um=0.0,
                                 model_um=0.0, state="ok", valid=k != 2,
                                 channels={"bearing": None if k == 2 else 20.0}))
    with pytest.raises(RecordError, match=r"row 4, column 'bearing': empty cell"):
        read_record(_export(db, tmp_path / "run.csv"))


def test_replay_fit_and_refine_take_what_export_wrote(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    db = _recorder(tmp_path / "samples.sqlite", 1440)
    csv_path = _export(db, tmp_path / "run.csv")
    capsys.readouterr()
    model = tmp_path / "m.toml"
    assert main(["fit", str(csv_path), "--column", "dz_um", "--term", "bearing",
                 "--term", "ambient", "-o", str(model)]) == 0, capsys.readouterr().err
    capsys.readouterr()
    figures = []
    for record in (db, csv_path):
        assert main(["replay", str(model), str(record), "--column", "dz_um", "--json"]) == 0
        figures.append(json.loads(capsys.readouterr().out.splitlines()[-1]))
    assert figures[0]["fit_percent"] == figures[1]["fit_percent"] > 90.0
    # refine takes probes; an export of samples has none, and says so in one line
    assert main(["refine", str(model), str(csv_path), "-o", str(tmp_path / "r.toml")]) == 65
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "measured_um" in err and "not a number" not in err


def test_fit_without_o_writes_nothing_beside_the_records(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    csv_path = _export(_recorder(tmp_path / "samples.sqlite", 400), tmp_path / "run.csv")
    before = sorted(p.name for p in tmp_path.iterdir())
    capsys.readouterr()
    assert main(["fit", str(csv_path), "--column", "dz_um", "--term", "bearing"]) == 64
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "-o MODEL.toml is required" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == before
