"""`compd fit` on the real record (tests/data/fl_thermal), through the command
line, kept short: the forward split's calibration rows at 1 min (a quarter
of the rows: the search decimates to about this anyway), one channel, the
troublesome inputs, low orders. The benchmark does the full run
(benchmarks/bench_real_record.py)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from compd.cli import main

RECORD = Path(__file__).resolve().parents[2] / "data" / "fl_thermal" / "calibration.csv"
#: the calibration rows of the forward split: t < 20.1 h
SPLIT_S = 20.1 * 3600.0


@pytest.fixture(scope="module")
def calibration(tmp_path_factory: pytest.TempPathFactory) -> Path:
    lines = RECORD.read_text().splitlines()
    keep = [ln for ln in lines[1:] if float(ln.split(",", 1)[0]) < SPLIT_S]
    out = tmp_path_factory.mktemp("fl") / "cal.csv"
    out.write_text("\n".join([lines[0], *keep[::4]]) + "\n")
    return out


def test_ch4_never_gets_the_cancelling_model(calibration: Path, tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    """The inputs whose DC gains come out at -36 and +213 µm/K unchecked: the
    search may offer them, the fit never writes a model its own diagnostics
    reject, and `compd check` finds nothing implausible in what it wrote."""
    model = tmp_path / "ch4.toml"
    assert main(["fit", str(calibration), "--column", "ch4_um", "--candidates", "t2_degC",
                 "--candidates", "t4_degC", "--candidates", "t15_degC", "--max-terms", "3",
                 "--orders", "1-2", "-o", str(model), "--json"]) == 0
    fit = json.loads(capsys.readouterr().out)
    sel = fit["terms"][0]["selection"]
    assert sel["heldout_rms_um"] < sel["displacement_rms_um"]
    for t in fit["terms"]:
        assert abs(t["dc_gain_um_per_k"]) * t["input_span"] <= 4.0 * t["output_span_um"]
    assert main(["check", str(model), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["implausible"] == []


def test_the_fixed_screen_wins_where_its_choice_validates_far_better(
        calibration: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """ch3 over six temperatures: the flexible screen alone chose t4 + t13
    (its structures validate at 16 %); the fixed ARX(2, 3) screen's
    t4 + t8 + t11 validates at 74 % and is written. Both screens' subsets are
    in the table, each marked with its screen."""
    names = ["t3_degC", "t4_degC", "t8_degC", "t11_degC", "t12_degC", "t13_degC"]
    model = tmp_path / "ch3.toml"
    assert main(["fit", str(calibration), "--column", "ch3_um",
                 *[a for n in names for a in ("--candidates", n)], "--max-terms", "3",
                 "-o", str(model), "--json"]) == 0
    fit = json.loads(capsys.readouterr().out)
    assert sorted(t["name"] for t in fit["terms"]) == ["t11_degC", "t4_degC", "t8_degC"]
    assert fit["terms"][0]["selection"]["validation_fit_percent"] > 70.0
    assert {s["screen"] for s in fit["subsets"]} == {"flexible", "arx"}
    assert main(["check", str(model), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["implausible"] == []
