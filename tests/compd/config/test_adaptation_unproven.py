"""No path to the worse adaptation: settings not learnt for the model (the library's
defaults on an old or bundled model) start stood down and must earn their place from
the probes (`models.adaptation`), and `compd check` says so of a config that applies
them."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from compd.cli import main
from compd.config.loader import load_config
from models.adaptation import AdaptationParams, Adapter, mark_unproven
from models.modelfile import library_path
from tests.compd.config.test_adaptation_config import ADAPTATION
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
