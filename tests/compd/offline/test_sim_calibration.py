"""The bundled model of the simulated machine (models/library/sim_machine.toml)
on a freshly generated spindle-speed spectrum run it was not fitted on (another
seed): `compd replay` reaches the calibration figure (>= 85 % fit, >= 6x range
reduction), and the model uses only the plant's channel names."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from compd.cli import main
from compd.infiles import load_model
from drivers.sim.csvlog import RECORD_COLUMNS


def test_the_bundled_model_uses_the_plants_channels() -> None:
    model = load_model("sim_machine")
    assert model.period_s == 60.0
    assert model.channels <= set(RECORD_COLUMNS) - {"time_s", "dz_um"}
    assert "verification" in model.provenance and model.provenance["data_sha256s"]


@pytest.mark.parametrize("seed", [7, 12])
def test_replay_on_a_fresh_spectrum_run(seed: int, tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    rec = tmp_path / "spectrum.csv"
    assert main(["sim", "--record", str(rec), "--program", "spectrum", "--period-s", "60",
                 "--seed", str(seed)]) == 0
    capsys.readouterr()
    assert main(["replay", "sim_machine", str(rec), "--column", "dz_um", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["fit_percent"] >= 85.0
    assert out["range_reduction"] >= 6.0


def test_replay_reads_the_daemons_recorder_database(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    from compd.offline.records import read_csv_record
    from compd.runtime.recorder import Recorder, RecordRow

    csv_path, db_path = tmp_path / "spectrum.csv", tmp_path / "spectrum.db"
    assert main(["sim", "--record", str(csv_path), "--program", "spectrum", "--period-s", "60",
                 "--seed", "7"]) == 0
    record = read_csv_record(csv_path)
    with Recorder(db_path, commit_every=100) as rec:
        for k, sample in enumerate(record.samples()):
            rec.record(RecordRow(seq=k, mono_s=float(record.time_s[k]), wall_s=1e9 + k,
                                 offset_um=0.0, model_um=0.0, state="running", valid=True,
                                 channels=sample))
    capsys.readouterr()
    figures = []
    for path in (csv_path, db_path):
        assert main(["replay", "sim_machine", str(path), "--column", "dz_um", "--json"]) == 0
        figures.append(json.loads(capsys.readouterr().out))
    assert figures[1] == pytest.approx(figures[0])
    assert main(["fit", str(db_path), "--column", "dz_um", "--term", "bearing", "--term",
                 "column", "--orders", "1-2", "-o", str(tmp_path / "from_db.toml")]) == 0
