"""Adaptation learnt from the machine, keeping score of itself, on the real record.

`compd fit --adaptation` writes what it learnt into the model file ([adaptation]);
`compd replay --probe-every-min` and the daemon's config use it unless told otherwise; the
estimator stands down while its score says adapting does not pay.
"""

from __future__ import annotations

import csv
import json
import tomllib
from pathlib import Path
from typing import Any

import pytest

from compd.cli import main
from compd.config.loader import load_config
from compd.core.adaptation import ProbeStage
from compd.core.cycle import params_from_config
from compd.core.faults import Event
from compd.errors import EX_CONFIG, ConfigError
from models.adaptation import AdaptationParams, Adapter
from models.errors import ModelError
from models.modelfile import parse_model
from tests.compd.config.test_adaptation_config import ADAPTATION
from tests.configs import MINIMAL
from tests.shipped import LIBRARY

RECORD = Path(__file__).resolve().parents[2] / "data" / "fl_thermal" / "calibration.csv"
SPLIT_S = 72360.0  # 20.1 h: calibrate before, score after
TERMS = ["--term", "t4_degC", "--term", "t6_degC"]


def _cli(argv: list[str], capsys: pytest.CaptureFixture[str]) -> dict[str, Any]:
    assert main(argv) == 0
    out: dict[str, Any] = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    return out


@pytest.fixture(scope="module")
def first_part(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("real") / "first.csv"
    with RECORD.open(newline="") as src, out.open("w", newline="") as dst:
        rows = csv.reader(src)
        w = csv.writer(dst)
        w.writerow(next(rows))
        w.writerows(r for r in rows if float(r[0]) <= SPLIT_S)
    return out


def _fit(first: Path, lag_s: int, capsys: pytest.CaptureFixture[str],
         column: str = "ch3_um") -> Path:
    model = first.parent / f"{column}-{lag_s}.toml"
    if not model.exists():
        _cli(["fit", str(first), "--column", column, *TERMS, "--adaptation",
              "--adaptation-lag-s", str(lag_s), "-o", str(model), "--json"], capsys)
    return model


def _replay(model: Path, every_s: int, capsys: pytest.CaptureFixture[str],
            *extra: str, column: str = "ch3_um") -> dict[str, Any]:
    return _cli(["replay", str(model), str(RECORD), "--column", column, "--init", "rest",
                 "--score-from", f"{SPLIT_S:g}", "--probe-every-min", f"{every_s / 60:g}",
                 "--json", *extra], capsys)


def test_fit_writes_the_learnt_settings_into_the_model_file(
        first_part: Path, capsys: pytest.CaptureFixture[str]) -> None:
    table = tomllib.loads(_fit(first_part, 7200, capsys).read_text())["adaptation"]
    # this machine's error moves by µm within hours: far beyond the 0.3 µm/√h default,
    # and beyond its fast noise, so the apply band is off
    assert 1.0 < table["bias_rw_um_per_sqrt_h"] < 10.0
    assert 0.01 <= table["probe_noise_um"] < 0.5
    assert table["apply_sigma"] == 0.0
    assert table["max_step_um"] > AdaptationParams().max_step_um
    # a correction held for up to 2 h beat the plain model on the calibration rows
    assert table["score_prior_adapted_um"] < table["score_prior_plain_um"]


def test_fit_learns_the_drift_on_rows_the_model_was_not_calibrated_on(
        first_part: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The residual on its own calibration rows said 2.9 µm/√h at 2 h; the forward
    folds' held-out blocks say 6.95 (production probes on this machine: about 10)."""
    model = first_part.parent / "ch3-heldout.toml"
    out = _cli(["fit", str(first_part), "--column", "ch3_um", *TERMS, "--adaptation",
                "--adaptation-lag-s", "7200", "-o", str(model), "--json"], capsys)
    adapt = out["adaptation"]
    assert adapt["drift_from"] == "rows the model was not calibrated on"
    assert 5.0 < adapt["bias_rw_um_per_sqrt_h"] < 15.0
    # the written table holds AdaptationParams keys only
    assert "drift_from" not in tomllib.loads(model.read_text())["adaptation"]
    # 4 h blocks hold no pair 8 h apart: the calibration residual says it
    long = _cli(["fit", str(first_part), "--column", "ch3_um", *TERMS, "--adaptation",
                 "--adaptation-lag-s", "28800", "-o", str(first_part.parent / "l.toml"),
                 "--json"], capsys)
    assert long["adaptation"]["drift_from"] == "the calibration residual"


@pytest.mark.parametrize("column", ["ch3_um", "ch4_um"])
@pytest.mark.parametrize("every_s", [3600, 7200])
def test_with_noisy_probes_the_learnt_estimator_is_at_least_as_good_as_crude(
        first_part: Path, capsys: pytest.CaptureFixture[str], every_s: int,
        column: str) -> None:
    """0.5 µm of probe noise against a learnt drift of 5-8 µm/√h: each probe is precise and
    taken whole. Weighed with the optimal gain (0.99) the estimator lagged this machine's
    trend by 0.4-0.6 % of RMS behind crude; from the calibration residual alone, 1.7 %."""
    model = _fit(first_part, every_s, capsys, column)
    r = _replay(model, every_s, capsys, "--probe-noise-um", "0.5", column=column)
    a, crude = r["adapted"], r["crude"]
    assert a["residue_rms_um"] <= crude["residue_rms_um"] + 1e-6
    assert a["residue_rms_um"] < 0.9 * a["plain_residue_rms_um"]


def test_replay_with_the_learnt_settings_matches_the_crude_baseline_at_1_h(
        first_part: Path, capsys: pytest.CaptureFixture[str]) -> None:
    model = _fit(first_part, 3600, capsys)
    learnt = _replay(model, 3600, capsys)
    a, crude = learnt["adapted"], learnt["crude"]
    assert learnt["adaptation_from"] == "model"
    assert a["probes_refused"] == 0 and a["stand_downs"] == 0
    assert a["residue_rms_um"] <= crude["residue_rms_um"] + 1e-6
    # well below the plain model's (the figure depends on the model fit chooses)
    assert a["residue_rms_um"] < 0.6 * a["plain_residue_rms_um"]
    defaults = _replay(model, 3600, capsys, "--adaptation-defaults")["adapted"]
    # the defaults lag far and are not learnt for this model: they start stood down and
    # apply only what the probes have shown pays, never worse than the plain model
    assert defaults["residue_rms_um"] <= a["plain_residue_rms_um"] + 1e-9
    assert defaults["probes_refused"] > 0
    # an option still overrides the model's table
    over = _replay(model, 3600, capsys, "--apply-sigma", "4")
    assert over["adaptation"]["apply_sigma"] == 4.0
    assert over["adaptation"]["bias_rw_um_per_sqrt_h"] == learnt["adaptation"][
        "bias_rw_um_per_sqrt_h"]


def test_at_2_h_a_warm_up_that_scatters_does_not_stand_it_down(
        first_part: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """ch3 every 2 h: two warm-up probes 8 µm apart once made the score stand down for
    the rest of the record (6.12 µm, plain, where crude is 5.21); the score's evidence is
    now weighed against its scatter."""
    model = _fit(first_part, 7200, capsys)
    r = _replay(model, 7200, capsys)
    a, crude = r["adapted"], r["crude"]
    assert a["stand_downs"] == 0
    assert a["residue_rms_um"] <= crude["residue_rms_um"] + 1e-6
    assert a["residue_rms_um"] < 0.9 * a["plain_residue_rms_um"]


@pytest.mark.parametrize("every_s", [7200, 14400, 28800])
def test_at_any_probe_spacing_the_learnt_estimator_is_never_worse_than_plain(
        first_part: Path, capsys: pytest.CaptureFixture[str], every_s: int) -> None:
    model = _fit(first_part, every_s, capsys)
    for noise in ("0", "0.5"):
        r = _replay(model, every_s, capsys, "--probe-noise-um", noise)
        assert r["adapted"]["residue_rms_um"] <= r["adapted"]["plain_residue_rms_um"] + 1e-9


def test_at_a_probe_spacing_that_does_not_pay_it_starts_stood_down(
        first_part: Path, capsys: pytest.CaptureFixture[str]) -> None:
    model = _fit(first_part, 28800, capsys)
    table = tomllib.loads(model.read_text())["adaptation"]
    assert table["score_prior_adapted_um"] > table["score_prior_plain_um"]
    for noise in ("0", "0.5"):
        r = _replay(model, 28800, capsys, "--probe-noise-um", noise)
        assert r["adapted"]["residue_rms_um"] <= r["adapted"]["plain_residue_rms_um"] + 1e-9
        # without its score the held correction made the machine worse than none
        unscored = _replay(model, 28800, capsys, "--probe-noise-um", noise,
                           "--score-window", "0")["adapted"]
        assert unscored["residue_rms_um"] > unscored["plain_residue_rms_um"]


# -- the score (models.adaptation) ----------------------------------------------------------

def _chasing() -> Adapter:
    """An estimator that follows every probe: it only chases the noise of a right model."""
    return Adapter(AdaptationParams(bias_rw_um_per_sqrt_h=20.0, probe_noise_um=0.5,
                                    apply_sigma=0.0, gate_sigma=10.0), 1)


def test_the_estimator_stands_down_when_adapting_does_not_pay_and_takes_over_when_it_does(
        ) -> None:
    a = _chasing()
    for z in (2.0, -2.0, 2.0, -2.0):  # the model is right: the probes scatter about it
        a.advance(3600.0)
        out = a.update(z, 0.0, [])
    assert out.standing_down and a.standing_down and a.stand_downs == 1
    assert a.correction_um([]) == 0.0  # the plain model
    assert a.estimated_bias_um != 0.0  # the filter still learns
    plain, adapted = a.score_um
    assert adapted > plain
    for _ in range(4):  # then the machine really moves by 6 µm: adapting pays again
        a.advance(3600.0)
        out = a.update(6.0, 0.0, [])
    assert not out.standing_down and a.correction_um([]) == pytest.approx(6.0, abs=0.5)
    assert a.stand_downs == 1
    b = Adapter.from_state(a.params, 1, json.loads(json.dumps(a.export_state())))
    assert b.export_state() == a.export_state() and b.score_um == a.score_um


def test_probes_that_scatter_about_a_tie_do_not_switch_it() -> None:
    """The paired difference adapted² − plain² must be beyond one standard error of its
    mean to move the estimator; a window that scatters about zero leaves it where it is."""
    from models.adaptation import _score_verdict

    p = AdaptationParams(score_window=5)
    tie = [(10.0, 60.0), (60.0, 10.0), (1.0, 20.0), (20.0, 1.0), (5.0, 6.0)]
    assert _score_verdict(tie, p, False) is False
    assert _score_verdict(tie, p, True) is True
    losing = [(1.0, 9.0), (2.0, 11.0), (1.0, 8.0)]
    assert _score_verdict(losing, p, False) is True
    assert _score_verdict([(a, p_) for p_, a in losing], p, True) is False
    # the prior counts as probes of its own difference
    prior = AdaptationParams(score_window=3, score_prior_plain_um=1.0,
                             score_prior_adapted_um=3.0, score_prior_probes=10)
    assert _score_verdict([(4.0, 3.0), (5.0, 4.0), (4.0, 3.5)], prior, False) is True


def test_a_change_it_cannot_hold_stands_a_stale_correction_down() -> None:
    """Probes refused again and again in one direction, beyond what the correction may
    hold (max_total_um): the correction applied before is stale and stands down at the
    reacquire_after-th refusal (the real record calibrated on 14 h: a -6 µm correction held
    while the residual climbed to +37 µm made the machine worse than plain)."""
    a = Adapter(AdaptationParams(bias_rw_um_per_sqrt_h=2.0, probe_noise_um=0.05,
                                 apply_sigma=0.0, max_total_um=20.0, reacquire_after=3), 1)
    for z in (-2.0, -4.0, -6.0):
        a.advance(3600.0)
        assert a.update(z, 0.0, []).accepted
    assert a.correction_um([]) < -3.0 and not a.standing_down
    outs = []
    for z in (25.0, 30.0, 35.0):
        a.advance(3600.0)
        outs.append(a.update(z, 0.0, []))
    assert [o.accepted for o in outs] == [False, False, False]
    assert a.standing_down and a.stand_downs == 1 and a.correction_um([]) == 0.0
    plain, adapted = a.score_um  # the refused probes were scored: the correction lost
    assert adapted > plain


def test_score_window_0_never_stands_down() -> None:
    a = Adapter(AdaptationParams(bias_rw_um_per_sqrt_h=20.0, apply_sigma=0.0,
                                 gate_sigma=10.0, score_window=0), 1)
    for z in (2.0, -2.0, 2.0, -2.0):
        a.advance(3600.0)
        a.update(z, 0.0, [])
    assert not a.standing_down and a.correction_um([]) != 0.0


def test_a_prior_saying_adapting_does_not_pay_starts_stood_down() -> None:
    a = Adapter(AdaptationParams(score_prior_plain_um=2.0, score_prior_adapted_um=4.0), 1)
    assert a.standing_down and a.correction_um([]) == 0.0


def test_a_stand_down_in_the_cycle_is_an_event_with_the_score() -> None:
    from compd.core.adaptation import AdaptationSettings, ProbeReading

    stage = ProbeStage(AdaptationSettings("apply", "displacement", _chasing().params), 1)
    events: list[Event] = []
    stage.step(1.0, ProbeReading(0.0, 1.0), complete=True, model_um=0.0, terms_um=[0.0],
               offset_in_force_um=0.0, events=events)  # the baseline counter
    for k, z in enumerate((2.0, -2.0, 2.0, -2.0)):
        stage.step(3600.0, ProbeReading(z, 2.0 + k), complete=True, model_um=0.0,
                   terms_um=[0.0], offset_in_force_um=0.0, events=events)
    down = [e for e in events if e.name == "adaptation_stood_down"]
    assert len(down) == 1
    assert down[0].fields["adapted_rms_um"] > down[0].fields["plain_rms_um"]
    assert stage.last is not None and stage.last["standing_down"] is True
    assert stage.step(1.0, None, complete=True, model_um=0.0, terms_um=[0.0],
                      offset_in_force_um=0.0, events=events) == 0.0


# -- the model file's table and the daemon's config -----------------------------------------

_TERMS = [{"name": "spindle", "kind": "tf", "inputs": {"bearing": 1.0},
           "a": ["0.1"], "b": ["1", "-0.9"]}]


@pytest.mark.parametrize(("table", "words"), [
    ({"bias_rw": 1.0}, "adaptation: unknown key(s) ['bias_rw']"),
    ({"probe_noise_um": -1.0}, "adaptation.probe_noise_um: must be > 0"),
    ({"apply_sigma": "x"}, "adaptation.apply_sigma: must be a finite number"),
])
def test_a_bad_adaptation_table_in_a_model_file_is_refused_by_name(
        table: dict[str, Any], words: str) -> None:
    with pytest.raises(ModelError, match=r"^model\." + words.replace("(", r"\(").replace(
            ")", r"\)").replace("[", r"\[").replace("]", r"\]")):
        parse_model({"model": {"name": "m", "period_s": 1.0}, "terms": _TERMS,
                     "adaptation": table})


def _model_with(tmp_path: Path, table: str) -> str:
    src = LIBRARY / "sp2.toml"
    p = tmp_path / "learnt.toml"
    p.write_text(src.read_text() + "\n[adaptation]\n" + table, encoding="utf-8")
    return MINIMAL.replace('file = "sp2"', f'file = "{p}"')


def test_the_daemon_uses_the_model_files_table_unless_the_config_overrides_it(
        tmp_path: Path) -> None:
    base = _model_with(tmp_path, "bias_rw_um_per_sqrt_h = 2.5\nprobe_noise_um = 0.07\n"
                                 "apply_sigma = 0.0\nmax_step_um = 1e6\n")
    cfg_path = tmp_path / "compd.toml"
    cfg_path.write_text(base + ADAPTATION, encoding="utf-8")
    p = params_from_config(load_config(cfg_path)).adaptation
    assert p is not None
    assert p.params.bias_rw_um_per_sqrt_h == 2.5 and p.params.apply_sigma == 0.0
    assert p.params.probe_noise_um == 0.8  # the config's own value wins
    limit = load_config(cfg_path).raw.output.limit_um
    assert p.params.max_step_um == limit  # no further than the output stage may write


def test_a_model_table_beyond_the_configs_bounds_is_refused_by_name(tmp_path: Path,
                                                                     capsys: Any) -> None:
    base = _model_with(tmp_path, "gate_sigma = 1e6\n")
    cfg_path = tmp_path / "compd.toml"
    cfg_path.write_text(base + ADAPTATION, encoding="utf-8")
    with pytest.raises(ConfigError) as exc:
        load_config(cfg_path)
    assert exc.value.key == "model [adaptation].gate_sigma"
    assert main(["check", str(cfg_path)]) == EX_CONFIG
    assert "gate_sigma" in capsys.readouterr().err


def test_a_reacquisition_in_the_cycle_is_an_event() -> None:
    from compd.core.adaptation import AdaptationSettings, ProbeReading

    stage = ProbeStage(AdaptationSettings("apply", "displacement",
                                          AdaptationParams(score_window=0)), 1)
    events: list[Event] = []
    values = [0.0] * 25 + [15.0] * 3  # a day right, then a real 15 µm change
    for k, z in enumerate(values):
        stage.step(3600.0, ProbeReading(z, float(k)), complete=True, model_um=0.0,
                   terms_um=[0.0], offset_in_force_um=0.0, events=events)
    names: list[str] = [e.name for e in events]
    assert names.count("probe_refused") == 2
    (ev,) = [e for e in events if e.name == "adaptation_reacquired"]
    assert ev.fields["refusals"] == 3 and ev.fields["innovation_um"] > 10.0
    assert stage.correction_um == pytest.approx(5.0)  # the first step, max_step_um


@pytest.mark.parametrize(("line", "key"), [
    ("guard_window = 101", "adaptation.guard_window"),
    ("guard_window = -1", "adaptation.guard_window"),
    ("reacquire_after = 1.5", "adaptation.reacquire_after"),
    ("score_window = 1000", "adaptation.score_window"),
])
def test_the_new_adaptation_keys_are_bounded_by_name(tmp_path: Path, line: str,
                                                     key: str) -> None:
    cfg_path = tmp_path / "compd.toml"
    cfg_path.write_text(MINIMAL + ADAPTATION + line + "\n", encoding="utf-8")
    with pytest.raises(ConfigError) as exc:
        load_config(cfg_path)
    assert exc.value.key == key


def test_the_guard_and_reacquire_keys_reach_the_cycle(tmp_path: Path) -> None:
    cfg_path = tmp_path / "compd.toml"
    cfg_path.write_text(MINIMAL + ADAPTATION + "guard_window = 5\nreacquire_after = 4\n",
                        encoding="utf-8")
    p = params_from_config(load_config(cfg_path)).adaptation
    assert p is not None and p.guard_window == 5 and p.params.reacquire_after == 4
