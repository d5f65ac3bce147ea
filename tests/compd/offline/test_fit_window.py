"""`compd fit --from S --until U`: the calibration rows, as `replay --score-from /
--score-until`. The rows after U are not read (the model is causal: the same model as
the record cut there); the rows before S run through the model from the record's start
and stay outside every loss."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from compd.cli import main
from compd.infiles import load_model
from compd.sysexits import EX_USAGE
from models.identify.segments import Segments
from models.identify.validate import usable_splits
from models.tf import TransferFunction

RECORD = Path(__file__).resolve().parents[2] / "data" / "fl_thermal" / "calibration.csv"


def test_until_is_the_record_cut_there(tmp_path: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    """The real record at 1 min: --until 72360 gives the model awk's cut gives."""
    lines = RECORD.read_text().splitlines()
    rows = lines[1::4]
    whole, cut = tmp_path / "whole.csv", tmp_path / "cut.csv"
    whole.write_text("\n".join([lines[0], *rows]) + "\n")
    cut.write_text("\n".join([lines[0], *[r for r in rows if float(r.split(",", 1)[0])
                                          <= 72360.0]]) + "\n")
    common = ["--column", "ch4_um", "--term", "t4_degC", "--term", "t6_degC", "--orders", "1-2"]
    assert main(["fit", str(whole), *common, "--until", "72360", "-o",
                 str(tmp_path / "a.toml"), "--json"]) == 0
    a = json.loads(capsys.readouterr().out)
    assert main(["fit", str(cut), *common, "-o", str(tmp_path / "b.toml"), "--json"]) == 0
    b = json.loads(capsys.readouterr().out)
    assert a["fit_percent"] == b["fit_percent"]
    ma, mb = load_model(tmp_path / "a.toml"), load_model(tmp_path / "b.toml")
    for ta, tb in zip(ma.terms, mb.terms, strict=True):
        assert isinstance(ta.dynamics, TransferFunction)
        assert isinstance(tb.dynamics, TransferFunction)
        assert ta.dynamics.num == tb.dynamics.num and ta.dynamics.den == tb.dynamics.den
    assert ma.provenance["calibrated_until_s"] == 72360.0


def _spoilt_start(path: Path) -> None:
    """A first-order lag of t1 (pole 0.9, 2 µm/K); the displacement probe slipped for
    the first 300 rows (a 15 µm ramp the machine never made)."""
    rng = np.random.default_rng(7)
    t1 = 20.0 + np.repeat(rng.uniform(0.0, 3.0, 30), 40)
    y = np.zeros(t1.size)
    for k in range(1, t1.size):
        y[k] = 0.9 * y[k - 1] + 0.2 * (t1[k] - t1[0])
    measured = y + 0.05 * rng.standard_normal(t1.size)
    measured[:300] += np.linspace(0.0, 15.0, 300)
    path.write_text("time_s,t1_degC,dz_um\n" + "".join(
        f"{60 * i},{a:.4f},{b:.4f}\n" for i, (a, b) in enumerate(zip(t1, measured,
                                                                      strict=True))))


def test_from_keeps_the_rows_before_out_of_the_loss(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    data = tmp_path / "rec.csv"
    _spoilt_start(data)
    argv = ["fit", str(data), "--column", "dz_um", "--term", "t1_degC", "--orders", "1-1",
            "--json"]
    assert main([*argv, "--from", "18000", "-o", str(tmp_path / "w.toml")]) == 0
    windowed = json.loads(capsys.readouterr().out)["terms"][0]["dc_gain_um_per_k"]
    assert main([*argv, "--force", "-o", str(tmp_path / "all.toml")]) == 0  # worse than none
    spoilt = json.loads(capsys.readouterr().out)["terms"][0]["dc_gain_um_per_k"]
    assert abs(windowed - 2.0) < 0.05
    assert abs(spoilt - 2.0) > 0.2
    assert load_model(tmp_path / "w.toml").provenance["calibrated_from_s"] == 18000.0


@pytest.mark.parametrize(("extra", "words"), [
    (["--from", "18000", "--structure", "search"], "--from goes with --kind tf, without"),
    (["--from", "600", "--until", "60"], "--until 60 s is before --from 600 s"),
    (["--from", "71000"], "rows there"),
])
def test_a_window_it_cannot_use_is_one_line_and_64(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str],
        words: str) -> None:
    data = tmp_path / "rec.csv"
    _spoilt_start(data)
    assert main(["fit", str(data), "--column", "dz_um", "--term", "t1_degC", *extra, "-o",
                 str(tmp_path / "m.toml")]) == EX_USAGE
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and words in err
    assert not (tmp_path / "m.toml").exists()


def test_usable_splits_cut_the_folds_within_the_window() -> None:
    """The docstring's worked number: 10 rows, the window from row 4, 2 forward folds;
    rows 6-7 masked as well (a held-out block inside the window)."""
    window = np.arange(10) >= 4
    (t1, v1), (t2, v2) = usable_splits(Segments.single(10), 2, "forward", window)
    assert list(np.flatnonzero(t1)) == [4, 5] and list(np.flatnonzero(v1)) == [6, 7]
    assert list(np.flatnonzero(t2)) == [4, 5, 6, 7] and list(np.flatnonzero(v2)) == [8, 9]
    window[6:8] = False
    (t1, v1), (t2, v2) = usable_splits(Segments.single(10), 2, "forward", window)
    assert list(np.flatnonzero(t1)) == [4] and list(np.flatnonzero(v1)) == [5, 8]
    assert list(np.flatnonzero(t2)) == [4, 5, 8] and list(np.flatnonzero(v2)) == [9]


def test_from_with_candidates_searches_the_window_only(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """--from with --candidates: the input search counts only the window's rows too
    (one mask for every loss), so the spoilt start chooses nothing and the gain of the
    chosen t1 is the one of the window."""
    data = tmp_path / "rec.csv"
    _spoilt_start(data)
    rng = np.random.default_rng(3)
    lines = data.read_text().splitlines()
    # a second candidate that follows the spoilt ramp of the first 300 rows, else noise
    decoy = np.concatenate([np.linspace(0.0, 7.5, 300), rng.uniform(0.0, 0.2, len(lines) - 301)])
    data.write_text("\n".join([lines[0] + ",t2_degC"] + [f"{ln},{20.0 + v:.4f}" for ln, v
                                                         in zip(lines[1:], decoy, strict=True)])
                    + "\n")
    assert main(["fit", str(data), "--column", "dz_um", "--candidates", "t*", "--max-terms",
                 "1", "--orders", "1-1", "--from", "18000", "--no-fallbacks", "--json", "-o",
                 str(tmp_path / "m.toml")]) == 0
    out = json.loads(capsys.readouterr().out)
    t1 = [t for t in out["terms"] if t["inputs"] == {"t1_degC": 1.0}]
    assert t1 and abs(sum(t["dc_gain_um_per_k"] for t in t1) - 2.0) < 0.1
    assert load_model(tmp_path / "m.toml").provenance["calibrated_from_s"] == 18000.0
