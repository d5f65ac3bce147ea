"""`compd refine`: a model's [adaptation] settings from the probes a running machine took
(a record with probes refines them)."""

from __future__ import annotations

import csv
import json
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from compd.cli import main
from compd.offline.probes import refine_from_probes

_MODEL = """\
[model]
name = "z"
period_s = 60.0

[[terms]]
name = "spindle"
kind = "tf"
inputs = { bearing = 1.0 }
a = ["0.1"]
b = ["1", "-0.9"]

[adaptation]
bias_rw_um_per_sqrt_h = 0.5
probe_noise_um = 0.2
gate_sigma = 5.0
"""


def _walk(seed: int, times_s: np.ndarray, rw_um_per_sqrt_h: float,
          noise_um: float) -> np.ndarray:
    """A residual that is a random walk of the given rate, probed with the given noise."""
    rng = np.random.default_rng(seed)
    steps = rng.standard_normal(times_s.size) * rw_um_per_sqrt_h \
        * np.sqrt(np.diff(times_s, prepend=times_s[0]) / 3600.0)
    return np.cumsum(steps) + noise_um * rng.standard_normal(times_s.size)


def test_the_drift_is_recovered_at_equal_spacings_with_the_model_files_noise() -> None:
    t = np.arange(400) * 3600.0
    out = refine_from_probes(t, _walk(1, t, 3.0, 0.2), probe_noise_um=0.2)
    assert out.noise_from == "model file" and out.pairs == 399 and out.spacing_s == 3600.0
    assert out.suggestion.bias_rw_um_per_sqrt_h == pytest.approx(3.0, rel=0.15)
    # a held correction pays on a walk: the prior says so
    assert out.suggestion.held_rms_um < out.suggestion.plain_rms_um
    assert out.suggestion.prior_probes == 100.0  # the evidence weighs at most 100 probes


def test_varied_spacings_separate_the_probes_noise_from_the_drift() -> None:
    rng = np.random.default_rng(7)
    t = np.cumsum(rng.choice([1800.0, 7200.0], size=600))
    out = refine_from_probes(t, _walk(2, t, 2.0, 1.5), probe_noise_um=0.01)
    assert out.noise_from == "probes"
    assert out.suggestion.probe_noise_um == pytest.approx(1.5, rel=0.2)
    assert out.suggestion.bias_rw_um_per_sqrt_h == pytest.approx(2.0, rel=0.25)


def test_a_restart_or_a_long_break_is_not_one_spacing() -> None:
    t = np.concatenate([np.arange(10) * 3600.0, 1e6 + np.arange(10) * 3600.0,
                        np.arange(10) * 3600.0])  # a break, then a restart of the clock
    out = refine_from_probes(t, np.zeros(t.size), probe_noise_um=0.1)
    assert out.pairs == 27 and out.probes == 30
    assert out.suggestion.bias_rw_um_per_sqrt_h == 0.0


@pytest.mark.parametrize("n", [0, 1, 5])
def test_too_few_probes_say_so(n: int) -> None:
    with pytest.raises(ValueError, match="refining needs at least"):
        refine_from_probes(np.arange(n) * 60.0, np.zeros(n), probe_noise_um=0.1)


def _log(path: Path, t: np.ndarray, residual: np.ndarray) -> Path:
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["time_s", "measured_um", "model_um", "counter"])
        for k, (ti, ri) in enumerate(zip(t, residual, strict=True)):
            w.writerow([f"{ti:g}", f"{10.0 + ri:.6f}", "10.0", k])
    return path


def test_refine_writes_the_table_and_keeps_the_terms_and_the_users_keys(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    model = tmp_path / "m.toml"
    model.write_text(_MODEL)
    t = np.arange(200) * 7200.0
    log = _log(tmp_path / "probes.csv", t, _walk(3, t, 4.0, 0.2))
    out = tmp_path / "refined.toml"
    assert main(["refine", str(model), str(log), "-o", str(out), "--json"]) == 0
    figures = json.loads(capsys.readouterr().out)
    assert figures["probes"] == 200 and figures["spacing_s"] == 7200.0
    assert figures["before"]["bias_rw_um_per_sqrt_h"] == 0.5
    old, new = tomllib.loads(_MODEL), tomllib.loads(out.read_text())
    assert new["terms"] == old["terms"] and new["model"] == old["model"]
    assert new["adaptation"]["gate_sigma"] == 5.0  # a key refine does not learn stays
    assert new["adaptation"]["bias_rw_um_per_sqrt_h"] == pytest.approx(4.0, rel=0.2)
    assert new["adaptation"]["score_prior_adapted_um"] < new["adaptation"][
        "score_prior_plain_um"]
    prov = new["provenance"]["adaptation_refined"]
    assert prov["probes_file"] == str(log) and len(prov["probes_sha256"]) == 64
    # the refined file is a model every command takes, with the new table
    assert main(["check", str(out)]) == 0
    capsys.readouterr()
    # the text form says what changed and what the probes say
    assert main(["refine", str(model), str(log), "-o", str(out), "--force"]) == 0
    text = capsys.readouterr().out
    assert "bias_rw_um_per_sqrt_h" in text and "→" in text and "held correction" in text


def test_refine_reads_the_recorders_probes(tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    from compd.runtime.recorder import Recorder, RecordRow

    db = tmp_path / "samples.sqlite"
    t = np.arange(60) * 3600.0
    r = _walk(4, t, 2.0, 0.1)
    with Recorder(db, commit_every=10) as rec:
        for k in range(t.size):
            reason = None if k % 10 else ("fault" if k % 20 else "gate")
            probe = {"counter": float(k), "value_um": 1.0, "measured_um": 5.0 + r[k],
                     "model_um": 5.0, "accepted": reason is None, "reason": reason,
                     "mode": "apply"}
            rec.record(RecordRow(seq=k, mono_s=float(t[k]), wall_s=1e9 + t[k],
                                 offset_um=0.0, model_um=5.0, state="running", valid=True,
                                 channels={"bearing": 20.0}, probe=probe))
    model = tmp_path / "m.toml"
    model.write_text(_MODEL)
    out = tmp_path / "refined.toml"
    assert main(["refine", str(model), str(db), "-o", str(out), "--json"]) == 0
    figures = json.loads(capsys.readouterr().out)
    # the fault refusals measured nothing; the gate's refusals are kept (real moves)
    assert figures["left_out"] == 3 and figures["probes"] == 57
    assert math.isfinite(figures["after"]["bias_rw_um_per_sqrt_h"])


@pytest.mark.parametrize(("content", "words"), [
    ("time_s,measured_um\n0,1\n", "no column(s) ['model_um']"),
    ("t,measured_um,model_um\n0,1,1\n", "no time column"),
    ("time_s,measured_um,model_um\n0,1,x\n", "row 2, column 'model_um': 'x' is not a number"),
    ("time_s,measured_um,model_um\n5,1,1\n5,1,1\n", "row 3: time 5.0 does not follow"),
    ("time_s,measured_um,model_um\n0,1,1\n1,nan,1\n", "not finite"),
    ("time_s,measured_um,model_um\n0,1,1\n1,1\n", "row 3: 2 fields"),
    ("time_s,measured_um,model_um\n0,1,1\n3600,2,1\n", "2 usable probe(s)"),
])
def test_a_bad_probe_log_is_one_line_and_65(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                            content: str, words: str) -> None:
    model = tmp_path / "m.toml"
    model.write_text(_MODEL)
    log = tmp_path / "probes.csv"
    log.write_text(content)
    assert main(["refine", str(model), str(log), "-o", str(tmp_path / "o.toml")]) == 65
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1 and err.startswith("compd refine: ")
    assert not (tmp_path / "o.toml").exists()


def test_refine_never_writes_over_its_inputs_or_an_existing_file(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    model = tmp_path / "m.toml"
    model.write_text(_MODEL)
    t = np.arange(20) * 3600.0
    log = _log(tmp_path / "probes.csv", t, _walk(5, t, 1.0, 0.1))
    for target, force in ((model, True), (log, True)):
        assert main(["refine", str(model), str(log), "-o", str(target),
                     *(["--force"] if force else [])]) == 73
    (tmp_path / "o.toml").write_text("mine")
    assert main(["refine", str(model), str(log), "-o", str(tmp_path / "o.toml")]) == 73
    assert (tmp_path / "o.toml").read_text() == "mine"
    assert model.read_text() == _MODEL
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 3 and all("Traceback" not in line for line in err)


def test_a_garbage_database_or_model_is_one_line(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    model = tmp_path / "m.toml"
    model.write_text(_MODEL)
    db = tmp_path / "x.db"
    db.write_bytes(b"not sqlite at all" * 100)
    assert main(["refine", str(model), str(db), "-o", str(tmp_path / "o.toml")]) == 65
    bad = tmp_path / "bad.toml"
    bad.write_text("[model]\nperiod_s = -1\n")
    t = np.arange(20) * 3600.0
    log = _log(tmp_path / "probes.csv", t, np.zeros(t.size))
    assert main(["refine", str(bad), str(log), "-o", str(tmp_path / "o.toml")]) in (65, 78)
    assert main(["refine", str(model), str(tmp_path), "-o", str(tmp_path / "o.toml")]) == 66
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 3 and all(line.startswith("compd refine: ") or ": " in line
                                 for line in err)
    assert not (tmp_path / "o.toml").exists()


def test_a_setting_refined_to_zero_says_what_zero_means(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A drift refined from 0.5 to 0 is not "off": the line beside it says the probes
    show no drift beyond their noise, so the estimator learns one constant bias."""
    model = tmp_path / "m.toml"
    model.write_text(_MODEL)
    t = np.arange(200) * 7200.0
    log = _log(tmp_path / "probes.csv", t, np.zeros(t.size))
    assert main(["refine", str(model), str(log), "-o", str(tmp_path / "r.toml")]) == 0
    line = next(ln for ln in capsys.readouterr().out.splitlines()
                if "bias_rw_um_per_sqrt_h" in ln)
    assert "→ 0" in line and "no drift beyond their noise" in line, line
