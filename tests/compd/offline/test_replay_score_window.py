"""`compd replay` reports the field's figures (MAE and RMS of
the residue, µm) beside fit % and range reduction, and scores a block inside
a record (--score-from … --score-until)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from compd.cli import main
from compd.sysexits import EX_DATAERR, EX_USAGE


@pytest.fixture()
def files(tmp_path: Path) -> tuple[Path, Path, np.ndarray]:
    """A static 2 µm/K model and a record whose displacement is 2.5 µm/K:
    the residue is 0.5 µm/K times the temperature rise, known at every row."""
    model = tmp_path / "m.toml"
    model.write_text('[model]\nname = "static"\nperiod_s = 60.0\n\n[[terms]]\nname = "t1"\n'
                     'inputs = { t1 = 1.0 }\na = ["2.0"]\nb = ["1.0"]\n')
    t1 = 20.0 + np.concatenate([np.linspace(0.0, 4.0, 50), np.full(50, 4.0)])
    dz = 2.5 * (t1 - 20.0) + 0.2 * np.sin(np.arange(100))
    data = tmp_path / "rec.csv"
    data.write_text("time_s,t1,dz_um\n" + "".join(
        f"{60 * i},{float(a)!r},{float(b)!r}\n"
        for i, (a, b) in enumerate(zip(t1, dz, strict=True))))
    return model, data, dz - 2.0 * (t1 - 20.0)


def test_mae_and_rms_of_a_block(files: tuple[Path, Path, np.ndarray],
                                capsys: pytest.CaptureFixture[str]) -> None:
    model, data, res = files
    assert main(["replay", str(model), str(data), "--column", "dz_um", "--init", "rest",
                 "--score-from", "600", "--score-until", "2940", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    block = res[10:50]  # rows at 600 … 2940 s, both ends included
    assert out["scored_samples"] == 40
    assert out["mae_um"] == pytest.approx(float(np.mean(np.abs(block))))
    assert out["rms_um"] == pytest.approx(float(np.sqrt(np.mean(block ** 2))))
    assert out["residue_max_um"] == pytest.approx(float(block.max()))
    assert main(["replay", str(model), str(data), "--column", "dz_um", "--init", "rest",
                 "--score-from", "600", "--score-until", "2940"]) == 0
    text = capsys.readouterr().out
    assert "scored 40 from 600 s to 2940 s" in text
    assert f"MAE {np.mean(np.abs(block)):.3f} µm, RMS {np.sqrt(np.mean(block ** 2)):.3f} µm" \
        in text


def test_a_window_without_samples_is_one_line(files: tuple[Path, Path, np.ndarray],
                                              capsys: pytest.CaptureFixture[str]) -> None:
    model, data, _ = files
    assert main(["replay", str(model), str(data), "--column", "dz_um", "--score-from", "600",
                 "--score-until", "300"]) == EX_USAGE
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--score-until 300 s is before --score-from 600 s" in err
    assert main(["replay", str(model), str(data), "--column", "dz_um", "--score-from", "610",
                 "--score-until", "650"]) == EX_DATAERR
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--score-until 650 s: no sample" in err
