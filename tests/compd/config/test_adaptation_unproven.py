"""No path to the worse adaptation: settings not learnt for the model (the library's
defaults on an old or bundled model) start stood down and must earn their place from
the probes (`models.adaptation`), and `compd check` says so of a config that applies
them."""

from __future__ import annotations

import csv
import json
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from compd.cli import main
from compd.config.loader import load_config
from models.adaptation import (
    LEARNT_KEYS,
    AdaptationParams,
    Adapter,
    mark_unproven,
    with_probe_noise,
)
from models.modelfile import library_path
from tests.compd.config.test_adaptation_config import ADAPTATION
from tests.compd.offline.test_refine import _MODEL, _log, _walk
from tests.configs import MINIMAL, write_config

RECORD = Path(__file__).resolve().parents[2] / "data" / "fl_thermal" / "calibration.csv"
SPLIT_S = 72360.0  # 20.1 h: calibrate before, score after


def test_unproven_settings_start_stood_down_and_weigh_all_their_probes() -> None:
    """Losing early, then three good probes: a score of three probes took over (and
    lost on the real record); unproven settings weigh every probe they have."""
    probes = [(0.0, 5.0), (2.0, 7.0), (4.0, 0.0), (6.0, 1.0), (8.0, 1.0), (10.0, 1.0)]

    def run(params: AdaptationParams) -> list[bool]:
        a = Adapter(params, 1)
        down = []
        for i, (t, z) in enumerate(probes):
            if i:
                a.advance(3600.0 * (t - probes[i - 1][0]))
            a.update(z, 0.0, ())
            down.append(a.standing_down)
        return down

    learnt_like = AdaptationParams(bias_rw_um_per_sqrt_h=2.0, apply_sigma=0.0, gate_sigma=10.0)
    unproven = AdaptationParams(**mark_unproven({"bias_rw_um_per_sqrt_h": 2.0,
                                                 "apply_sigma": 0.0, "gate_sigma": 10.0}))
    assert unproven.unproven and not learnt_like.unproven
    assert Adapter(unproven, 1).standing_down and Adapter(unproven, 1).correction_um(()) == 0.0
    assert not Adapter(learnt_like, 1).standing_down
    assert run(unproven) == [True] * len(probes)
    assert run(learnt_like)[-1] is False  # the window of three took over
    # a learnt prior is what makes settings proven
    assert not AdaptationParams(**mark_unproven({"score_prior_plain_um": 1.0,
                                                 "score_prior_adapted_um": 0.5})).unproven


def _config(tmp_path: Path, model: str, mode: str = "apply") -> Path:
    return write_config(tmp_path, base=MINIMAL + ADAPTATION, file=model, mode=mode)


def test_check_says_when_apply_runs_on_settings_not_learnt_for_the_model(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    p = _config(tmp_path, "sp2")
    assert load_config(p).adaptation.params.unproven  # type: ignore[union-attr]
    assert main(["check", str(p)]) == 0
    err = capsys.readouterr().err
    assert "no [adaptation] settings learnt for it" in err and "starts stood down" in err
    assert main(["check", str(_config(tmp_path, "sp2", "shadow"))]) == 0
    assert "learnt for it" not in capsys.readouterr().err
    learnt = tmp_path / "sp2-learnt.toml"
    learnt.write_text(Path(str(library_path("sp2"))).read_text(encoding="utf-8")
                      + "\n[adaptation]\nscore_prior_plain_um = 1.0\n"
                      "score_prior_adapted_um = 0.5\nbias_rw_um_per_sqrt_h = 2.0\n",
                      encoding="utf-8")
    p = _config(tmp_path, str(learnt))
    assert not load_config(p).adaptation.params.unproven  # type: ignore[union-attr]
    assert main(["check", str(p)]) == 0
    assert "learnt for it" not in capsys.readouterr().err


def test_the_defaults_are_no_worse_than_plain_on_the_real_record(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """ch3, calibrated on the first 20.1 h, a probe every 2 h: the library's defaults
    made it worse than the plain model (7.17 against 6.26 µm RMS); unproven, they stand
    down."""
    first = tmp_path / "first.csv"
    with RECORD.open(newline="") as src, first.open("w", newline="") as dst:
        rows = csv.reader(src)
        w = csv.writer(dst)
        w.writerow(next(rows))
        w.writerows(r for r in rows if float(r[0]) <= SPLIT_S)
    model = tmp_path / "ch3.toml"
    assert main(["fit", str(first), "--column", "ch3_um", "--term", "t4_degC", "--term",
                 "t6_degC", "-o", str(model), "--json"]) == 0
    capsys.readouterr()
    assert main(["replay", str(model), str(RECORD), "--column", "ch3_um", "--init", "rest",
                 "--score-from", f"{SPLIT_S:g}", "--probe-every-min", "120",
                 "--adaptation-defaults", "--json"]) == 0
    adapted = json.loads(capsys.readouterr().out.strip().splitlines()[-1])["adapted"]
    assert adapted["residue_rms_um"] <= adapted["plain_residue_rms_um"] + 1e-9


def test_a_noisier_probe_than_the_record_weighs_on_the_learnt_prior() -> None:
    """A correction held from a probe noisier than the record's rows errs by the extra
    noise: the learnt prior of the adapted error grows by it, so a prior that barely
    favoured adapting (the shop machine's 1.151 against 1.18 µm) no longer does."""
    learnt: dict[str, Any] = {"probe_noise_um": 0.3, "score_prior_plain_um": 1.18,
              "score_prior_adapted_um": 1.151, "score_prior_probes": 12.0}
    noisy = with_probe_noise(learnt, 0.6)
    assert noisy["probe_noise_um"] == 0.6
    assert noisy["score_prior_adapted_um"] == pytest.approx(
        (1.151 ** 2 + 0.6 ** 2 - 0.3 ** 2) ** 0.5)
    assert Adapter(AdaptationParams(**noisy), 1).standing_down
    assert not Adapter(AdaptationParams(**learnt), 1).standing_down
    assert with_probe_noise(learnt, 0.1)["score_prior_adapted_um"] == 1.151  # quieter
    # the band decided again with the probe's noise: a drift of 1.467 µm/√h moves 2.07 µm
    # over 2 h, beyond 4 σ of the record's 0.3 µm, within 4 σ of a 0.6 µm probe
    follow = {**learnt, "bias_rw_um_per_sqrt_h": 1.467, "apply_sigma": 0.0}
    assert with_probe_noise(follow, 0.6)["apply_sigma"] == AdaptationParams.apply_sigma
    assert with_probe_noise(follow, 0.6, spacing_s=4 * 3600.0)["apply_sigma"] == 0.0
    assert with_probe_noise({**follow, "bias_rw_um_per_sqrt_h": 8.0}, 0.6)["apply_sigma"] == 0.0
    assert with_probe_noise({"bias_rw_um_per_sqrt_h": 2.0}, 0.6) == {
        "bias_rw_um_per_sqrt_h": 2.0, "probe_noise_um": 0.6}


def test_fit_learns_the_settings_or_says_why_not_and_check_names_it(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """compd fit --adaptation learns the settings; where it cannot (records shorter
    than the lag) or is not asked to, the model file says so and why, its [adaptation]
    table marks them unproven, and check's line on apply says the same."""
    first = tmp_path / "first.csv"
    with RECORD.open(newline="") as src, first.open("w", newline="") as dst:
        rows = csv.reader(src)
        w = csv.writer(dst)
        w.writerow(next(rows))
        w.writerows(r for r in rows if float(r[0]) <= SPLIT_S)
    fit = ["fit", str(first), "--column", "ch3_um", "--term", "t4_degC", "--term", "t6_degC",
           "--no-fallbacks", "--json"]
    assert main([*fit, "-o", str(tmp_path / "plain.toml")]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert "adaptation" not in out and "adaptation_not_learnt" not in out  # not asked
    doc = tomllib.loads((tmp_path / "plain.toml").read_text(encoding="utf-8"))
    assert doc["adaptation"] == {"unproven": True}
    assert "--adaptation" in doc["provenance"]["adaptation_not_learnt"]
    fit.append("--adaptation")
    assert main([*fit, "-o", str(tmp_path / "learnt.toml")]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    doc = tomllib.loads((tmp_path / "learnt.toml").read_text(encoding="utf-8"))
    assert "adaptation_not_learnt" not in out and "adaptation_not_learnt" not in doc["provenance"]
    assert all(k in doc["adaptation"] for k in LEARNT_KEYS)
    assert doc["provenance"]["adaptation_learnt_on"] == out["adaptation"]["drift_from"]
    model = tmp_path / "ch3.toml"
    assert main([*fit, "-o", str(model), "--adaptation-lag-s", "1e6"]) == 0
    captured = capsys.readouterr()
    out = json.loads(captured.out.strip().splitlines()[-1])
    assert "adaptation" not in out and "shorter than the lag" in out["adaptation_not_learnt"]
    assert "adaptation settings not learnt: the records are shorter" in captured.err
    doc = tomllib.loads(model.read_text(encoding="utf-8"))
    assert doc["adaptation"] == {"unproven": True}
    assert doc["provenance"]["adaptation_not_learnt"] == out["adaptation_not_learnt"]
    # the bundled sp2 (the config's channels) with what fit wrote of its adaptation
    sp2 = tmp_path / "sp2-fitted.toml"
    sp2.write_text(Path(str(library_path("sp2"))).read_text(encoding="utf-8")
                   + "\n[adaptation]\nunproven = true\n\n[provenance]\n"
                   f"adaptation_not_learnt = {json.dumps(out['adaptation_not_learnt'])}\n",
                   encoding="utf-8")
    cfg = _config(tmp_path, str(sp2))
    assert load_config(cfg).adaptation.params.unproven  # type: ignore[union-attr]
    assert main(["check", str(cfg)]) == 0
    lines = [ln for ln in capsys.readouterr().err.splitlines() if "adaptation.mode" in ln]
    assert len(lines) == 1 and "did not learn them: the records are shorter" in lines[0]


def test_refine_proves_a_table_fit_could_not_learn(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A model file whose [adaptation] table compd fit marked unproven, refined from a
    running machine's probes, carries a learnt prior and no longer starts stood down."""
    model = tmp_path / "m.toml"
    model.write_text(_MODEL.split("[adaptation]")[0] + "[adaptation]\nunproven = true\n",
                     encoding="utf-8")
    t = np.arange(200) * 7200.0
    log = _log(tmp_path / "probes.csv", t, _walk(3, t, 4.0, 0.2))
    out = tmp_path / "refined.toml"
    assert main(["refine", str(model), str(log), "-o", str(out)]) == 0
    capsys.readouterr()
    table = tomllib.loads(out.read_text(encoding="utf-8"))["adaptation"]
    assert "unproven" not in table and all(k in table for k in LEARNT_KEYS)
    assert not AdaptationParams(**mark_unproven(table)).unproven


def test_a_configs_noisier_probe_weighs_on_the_models_learnt_table(tmp_path: Path) -> None:
    """The config's probe_noise_um (0.8 µm) over a table learnt with the record's 0.3:
    the held correction's prior grows by the extra noise and the band is decided again."""
    learnt = tmp_path / "sp2-learnt.toml"
    learnt.write_text(Path(str(library_path("sp2"))).read_text(encoding="utf-8")
                      + "\n[adaptation]\nprobe_noise_um = 0.3\nbias_rw_um_per_sqrt_h = 1.467\n"
                      "apply_sigma = 0.0\nscore_prior_plain_um = 1.18\n"
                      "score_prior_adapted_um = 1.151\nscore_prior_probes = 12.0\n",
                      encoding="utf-8")
    params = load_config(_config(tmp_path, str(learnt))).adaptation.params  # type: ignore[union-attr]
    assert params.probe_noise_um == 0.8 and not params.unproven
    assert params.apply_sigma == AdaptationParams.apply_sigma
    assert params.score_prior_adapted_um == pytest.approx((1.151 ** 2 + 0.8 ** 2 - 0.09) ** 0.5)
    assert Adapter(params, 1).standing_down
