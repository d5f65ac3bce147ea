"""`compd fit` writes no model `compd check` would warn about, unless --force:
candidates whose model check flags are not chosen, fit falls back to the best
one without a warning and says why; with none, nothing is written (exit 65,
one line)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from compd.cli import main
from compd.sysexits import EX_DATAERR

RECORD = Path(__file__).resolve().parents[2] / "data" / "fl_thermal" / "calibration.csv"
#: the calibration rows of the benchmark's forward split: t < 20.1 h
SPLIT_S = 20.1 * 3600.0


@pytest.fixture(scope="module")
def calibration(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The real record's first 20.1 h at 1 min (every fourth row)."""
    lines = RECORD.read_text().splitlines()
    keep = [ln for ln in lines[1:] if float(ln.split(",", 1)[0]) < SPLIT_S]
    out = tmp_path_factory.mktemp("fl") / "cal.csv"
    out.write_text("\n".join([lines[0], *keep[::4]]) + "\n")
    return out


def test_the_real_ch3_model_falls_back_to_one_check_accepts(
        calibration: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """ch3 on t4 and t6: every structure at orders 2-4 has a negative real pole
    (the model fit wrote before); fit says so and writes a first-order one that
    `compd check` does not warn about."""
    model = tmp_path / "ch3.toml"
    assert main(["fit", str(calibration), "--column", "ch3_um", "--term", "t4_degC",
                 "--term", "t6_degC", "-o", str(model), "--json"]) == 0
    captured = capsys.readouterr()
    assert "compd fit: fell back to" in captured.err
    assert "negative real pole" in captured.err
    sel = json.loads(captured.out)["terms"][0]["selection"]
    assert any("compd check would warn" in n for n in sel["notes"])
    assert main(["check", str(model), "--json"]) == 0
    checked = capsys.readouterr()
    assert json.loads(checked.out)["implausible"] == []
    assert "warning" not in checked.err


def _record(path: Path) -> None:
    rng = np.random.default_rng(5)
    t1 = 20.0 + np.repeat(rng.uniform(0.0, 3.0, 20), 50)
    y = np.zeros(t1.size)
    for k in range(1, t1.size):  # a first-order lag, pole 0.9, 2 µm/K
        y[k] = 0.9 * y[k - 1] + 0.2 * (t1[k] - t1[0])
    y += 0.05 * rng.standard_normal(t1.size)
    path.write_text("time_s,t1_degC,dz_um\n" + "".join(
        f"{60 * i},{a:.4f},{b:.4f}\n" for i, (a, b) in enumerate(zip(t1, y, strict=True))))


def test_with_no_candidate_check_accepts_nothing_is_written(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Were check to warn about every model, fit exits 65 with one line and no
    file; --force writes the best validated one and repeats check's warnings."""
    from compd.offline import model_description

    def always(model: Any) -> list[str]:
        return [f"term {model.terms[0].name!r}: a warning for the test"]

    monkeypatch.setattr(model_description, "plausibility", always)
    data, out = tmp_path / "rec.csv", tmp_path / "m.toml"
    _record(data)
    argv = ["fit", str(data), "--column", "dz_um", "--term", "t1_degC", "-o", str(out)]
    assert main(argv) == EX_DATAERR
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert "a warning for the test" in err and "--force" in err
    assert not out.exists()
    assert main([*argv, "--force"]) == 0
    err = capsys.readouterr().err
    assert "compd check would warn: term 't1_degC': a warning for the test; written all the " \
           "same (--force)" in err
    assert out.exists()


def test_a_model_check_accepts_is_written_without_a_word(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    data, out = tmp_path / "rec.csv", tmp_path / "m.toml"
    _record(data)
    assert main(["fit", str(data), "--column", "dz_um", "--term", "t1_degC", "--orders", "1-1",
                 "-o", str(out)]) == 0
    assert "fell back" not in capsys.readouterr().err
    assert main(["check", str(out), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["implausible"] == []
