"""`compd fit`, `compd replay` and `compd step` end to end on records generated
by the papers' per-spindle model SP3 (ε_SP3 + ε_amb, paper 000): inputs
quantised to 0.1 K, 0.5 µm probe noise. SP3 is used because its DC gains are
well determined by the printed digits (ε_SP1's is not at all, see
models/sensitivity.py); SP2 works the same but needs longer records."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from compd.cli import main
from compd.infiles import load_model
from tests.compd.conftest import RecipePlant
from tests.compd.offline.records_gen import make_record


@pytest.fixture(scope="module")
def sp3_records(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    d = tmp_path_factory.mktemp("sp3")
    make_record(d / "cal.csv", "sp3", hours=6, seed=1)
    make_record(d / "ver.csv", "sp3", hours=6, seed=2)
    return d / "cal.csv", d / "ver.csv"


@pytest.fixture(scope="module")
def sp3_model(sp3_records: tuple[Path, Path]) -> Path:
    out = sp3_records[0].with_name("fitted.toml")
    assert main([
        "fit", str(sp3_records[0]), "--column", "dz_um", "--term", "spindle=bearing",
        "--term", "ambient", "--orders", "1-3", "-o", str(out)]) == 0
    return out


def test_fit_recovers_the_dc_gains_within_2_percent(sp3_model: Path) -> None:
    fitted = {t.name: t.dynamics.dc_gain for t in load_model(sp3_model).terms}
    truth = {t.name: t.dynamics.dc_gain for t in load_model("sp3").terms}
    for name in ("spindle", "ambient"):
        assert fitted[name] == pytest.approx(truth[name], rel=0.02)


def test_the_model_file_carries_provenance_and_exact_coefficients(sp3_model: Path,
                                                                  sp3_records: tuple[Path, Path]
                                                                  ) -> None:
    model = load_model(sp3_model)
    prov = model.provenance
    assert prov["data_sha256"] and prov["arx_fit_percent"] < prov["oe_fit_percent"]
    assert "spindle_orders" in prov and prov["command_line"].startswith("compd fit")
    assert model.period_s == 1.0
    text = sp3_model.read_text()
    for term in model.terms:
        for c in term.dynamics.num:  # type: ignore[union-attr]
            assert repr(c) in text or c == 0.0


def test_replay_verification_fit_at_least_95_percent(sp3_model: Path,
                                                      sp3_records: tuple[Path, Path],
                                                      capsys: pytest.CaptureFixture[str],
                                                      tmp_path: Path) -> None:
    png = tmp_path / "replay.png"
    assert main(["replay", str(sp3_model), str(sp3_records[1]), "--column", "dz_um",
                 "--plot", str(png), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) == {"fit_percent", "residue_min_um", "residue_max_um", "dpk_um",
                        "range_reduction", "mae_um", "rms_um", "init", "through",
                        "scored_samples"}
    assert out["init"] == "estimate" and out["scored_samples"] == 6 * 3600 + 1
    assert out["fit_percent"] >= 95.0
    assert out["dpk_um"] == pytest.approx(abs(out["residue_min_um"]) + abs(out["residue_max_um"]))
    assert png.stat().st_size > 10_000


def test_fit_json_and_a_fixed_term(sp3_records: tuple[Path, Path], tmp_path: Path,
                                   capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "spindle_only.toml"
    assert main(["fit", str(sp3_records[0]), "--column", "dz_um", "--term", "spindle=bearing",
                 "--fixed", "sp3:ambient", "--orders", "1-2", "-o", str(out), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert set(doc) == {"terms", "fit_percent", "dpk_um", "model_file", "records", "fallbacks"}
    assert [r["path"] for r in doc["records"]] == [str(sp3_records[0])]
    assert doc["model_file"] == str(out) and doc["fit_percent"] > 95.0
    model = load_model(out)
    assert [t.name for t in model.terms] == ["ambient", "spindle"]
    assert model.terms[1].dynamics.dc_gain == pytest.approx(11.11875, rel=0.02)


def test_replay_refuses_another_period_and_bad_data(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    rec = tmp_path / "ten.csv"
    rec.write_text("time_s,bearing,ambient,dz_um\n" + "".join(
        f"{10 * k},{20 + k / 10:.1f},20.0,{k * 1.5}\n" for k in range(20)))
    assert main(["replay", "sp3", str(rec), "--column", "dz_um"]) == 65
    assert "sampled every 10 s" in capsys.readouterr().err
    rec.write_text("time_s,bearing,ambient,dz_um\n0,20,20,1\n1,20,20,2\n1,20,20,3\n2,20,20,4\n")
    assert main(["fit", str(rec), "--column", "dz_um", "--term", "bearing",
                 "-o", str(tmp_path / "m.toml")]) == 65
    assert "duplicated timestamp" in capsys.readouterr().err


def test_step_json_and_plot(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    png = tmp_path / "step.png"
    assert main(["step", "sp3", "--plot", str(png), "--json"]) == 0
    terms = {t["name"]: t for t in json.loads(capsys.readouterr().out)["terms"]}
    assert terms["spindle"]["y0_um"] == pytest.approx(4.30702)
    assert terms["spindle"]["y_end_um"] == pytest.approx(11.11875, rel=0.01)
    assert png.stat().st_size > 10_000


def test_simulated_machine_calibration_generalises(recipe_plant: RecipePlant, tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    """The papers' calibration design on the simulated machine: a 9,000 rpm
    heat-up + cool-down and an environmental run fitted jointly (one term per
    sensor), verified on a spindle-speed spectrum run. At 60 s sampling; the
    ceiling set by the 0.5 µm probe noise alone is ~91 % / ~7x. (The papers'
    third order, --orders 3-3, leaves only a model compd check accepts below
    that: its output-error fits have a negative real pole, and its ARX 5.2x.)"""
    assert main(["sim", "--record", str(tmp_path / "spectrum.csv"), "--program", "spectrum",
                 "--period-s", "60", "--seed", "3"]) == 0
    full = recipe_plant.plant  # the constant (seed 2) and etve (seed 1) runs, fitted jointly
    capsys.readouterr()
    assert main(["replay", str(full), str(tmp_path / "spectrum.csv"), "--column", "dz_um",
                 "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["fit_percent"] >= 85.0 and out["range_reduction"] >= 6.0
    assert math.isfinite(out["dpk_um"])
    prov = load_model(full).provenance
    assert prov["samples_per_record"] == [481, 1441] and prov["max_time_constant_days"] == 3.0


def test_fit_refuses_records_with_different_periods_and_a_too_slow_pole(
        tmp_path: Path, sp3_records: tuple[Path, Path],
        capsys: pytest.CaptureFixture[str]) -> None:
    ten = tmp_path / "ten.csv"
    ten.write_text("time_s,bearing,ambient,dz_um\n" + "".join(
        f"{10 * k},{20 + k / 10:.1f},20.0,{k * 1.5}\n" for k in range(20)))
    assert main(["fit", str(sp3_records[0]), str(ten), "--column", "dz_um",
                 "--term", "bearing", "-o", str(tmp_path / "m.toml")]) == 65
    assert "need one sample period" in capsys.readouterr().err
    # SP3's spindle pole (0.9984 at 1 s, τ ≈ 10 min) is slower than a 1-minute bound:
    # every dynamic order fails, said, and the static model is what fits
    assert main(["fit", str(sp3_records[0]), "--column", "dz_um", "--term", "spindle=bearing",
                 "--fixed", "sp3:ambient", "--orders", "1-2", "--max-time-constant-days",
                 str(60 / 86400), "-o", str(tmp_path / "x.toml")]) == 0
    out = capsys.readouterr().out
    assert "failed: first order" in out and "slowest allowed time constant" in out
    assert "structure static" in out
