"""`compd replay VALUE DATA --slope-model SLOPE`: the error at every measured
position before and after the line of a value and a slope model, and the
refusals (one line, a sysexits code)."""

from __future__ import annotations

import json
import re
import shlex
from dataclasses import dataclass
from pathlib import Path

import pytest

from compd.cli import main
from compd.sysexits import EX_DATAERR, EX_USAGE

VALUE_TERMS = ["--term", "column", "--term", "screw_bearing", "--term", "ambient", "--term",
               "nut"]
SLOPE_TERMS = ["--term", "nut", "--term", "screw_bearing"]


@dataclass(frozen=True)
class Fitted:
    held: Path
    value: Path
    slope: Path
    #: the value fitted with its reference position at 400 mm
    value_400: Path
    folder: Path


def _fit(rec: Path, column: str, terms: list[str], out: Path, *extra: str) -> Path:
    assert main(["fit", str(rec), "--positions", "--column", column, *terms, *extra,
                 "--no-fallbacks", "--json", "-o", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def fitted(tmp_path_factory: pytest.TempPathFactory) -> Fitted:
    d = tmp_path_factory.mktemp("positions")
    train, held = d / "train.csv", d / "held.csv"
    assert main(["sim", "--machine", "ballscrew", "--record", str(train), "--hours", "36",
                 "--seed", "1"]) == 0
    assert main(["sim", "--machine", "ballscrew", "--record", str(held), "--hours", "12",
                 "--seed", "2"]) == 0
    return Fitted(held, _fit(train, "value_um", VALUE_TERMS, d / "value.toml"),
                  _fit(train, "slope_um_m", SLOPE_TERMS, d / "slope.toml"),
                  _fit(train, "value_um", VALUE_TERMS, d / "value400.toml",
                       "--reference-position-mm", "400"), d)


def _replay(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, list[str]]:
    capsys.readouterr()
    code = main(["replay", *argv])
    got = capsys.readouterr()
    return code, got.out, got.err.strip().splitlines()


def test_every_position_is_scored_before_and_after(fitted: Fitted,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = _replay(capsys, str(fitted.value), str(fitted.held), "--slope-model",
                           str(fitted.slope), "--init", "rest", "--json")
    assert code == 0
    doc = json.loads(out)
    assert [p["position_mm"] for p in doc["positions"]] == [0.0, 200.0, 400.0, 600.0, 800.0]
    # the screw grows from its fixed bearing: uncorrected, the error grows along the travel
    before = [p["before_mae_um"] for p in doc["positions"]]
    assert before == sorted(before) and before[-1] > 2 * before[0]
    for p in doc["positions"]:  # the line leaves about the 0.5 µm measuring noise
        assert p["after_mae_um"] < 1.0 < p["before_mae_um"]
    assert doc["after_rms_um"] < 0.1 * doc["before_rms_um"]
    assert doc["dependent_after_rms_um"] < 0.2 * doc["dependent_before_rms_um"]
    assert doc["reference_position_mm"] == 0.0 and doc["reference_from"] == "models"
    assert doc["scored_samples"] == 12 * 12 + 1


def test_at_the_reference_position_the_value_model_alone_is_scored(
        fitted: Fitted, capsys: pytest.CaptureFixture[str]) -> None:
    """At x0 the slope adds nothing: the figure is plain replay's of the value model
    on that position's column, computed by other code."""
    _, out, _ = _replay(capsys, str(fitted.value), str(fitted.held), "--slope-model",
                        str(fitted.slope), "--init", "rest", "--json", "--score-from", "7200")
    at0 = json.loads(out)["positions"][0]
    _, plain, _ = _replay(capsys, str(fitted.value), str(fitted.held), "--column",
                          "dx_at_0mm_um", "--init", "rest", "--json", "--score-from", "7200")
    single = json.loads(plain)
    assert at0["after_mae_um"] == pytest.approx(single["mae_um"], rel=1e-12)
    assert at0["after_rms_um"] == pytest.approx(single["rms_um"], rel=1e-12)


def test_the_text_table_names_each_position(fitted: Fitted,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = _replay(capsys, str(fitted.value), str(fitted.held), "--slope-model",
                           str(fitted.slope))
    assert code == 0
    lines = out.splitlines()
    assert "reference position 0 mm, as the models were fitted" in lines[0]
    assert [ln.split()[0] for ln in lines[2:7]] == ["0", "200", "400", "600", "800"]
    assert lines[7].split()[0] == "all" and "% removed" in lines[8]


def _one_line(capsys: pytest.CaptureFixture[str], code_wanted: int, says: str,
              *argv: str) -> None:
    code, _, err = _replay(capsys, *argv)
    assert code == code_wanted
    assert len(err) == 1 and says in err[0], err


def test_a_mismatched_model_is_refused(fitted: Fitted,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    held = str(fitted.held)
    _one_line(capsys, EX_DATAERR, "fitted on 'slope_um_m', not 'value_um'",
              str(fitted.slope), held, "--slope-model", str(fitted.value))
    _one_line(capsys, EX_DATAERR, "reference position is 400 mm, the slope model's 0 mm",
              str(fitted.value_400), held, "--slope-model", str(fitted.slope))
    _one_line(capsys, EX_DATAERR, "--reference-position-mm 100: the models were fitted "
              "with the value at 0 mm", str(fitted.value), held, "--slope-model",
              str(fitted.slope), "--reference-position-mm", "100")


def test_a_record_that_does_not_fit_the_models_is_refused(
        fitted: Fitted, capsys: pytest.CaptureFixture[str]) -> None:
    d = fitted.folder
    models = ["--slope-model", str(fitted.slope)]
    plain = d / "plain.csv"  # no position column
    plain.write_text("time_s,nut,screw_bearing,column,ambient,dz_um\n"
                     + "".join(f"{300 * k},20,20,20,20,{k}\n" for k in range(30)),
                     encoding="ascii")
    _one_line(capsys, EX_DATAERR, "value and slope need two or more columns dx_at_<x>mm_um",
              str(fitted.value), str(plain), *models)
    text = fitted.held.read_text(encoding="ascii").splitlines()
    head = text[0].split(",")
    one = d / "one.csv"  # a single position: no line through it
    keep = [i for i, c in enumerate(head) if not c.startswith("dx_at_") or c == "dx_at_0mm_um"]
    one.write_text("\n".join(",".join(r.split(",")[i] for i in keep) for r in text) + "\n",
                   encoding="ascii")
    _one_line(capsys, EX_DATAERR, "1 position(s) (dx_at_0mm_um)", str(fitted.value),
              str(one), *models)
    no_nut = d / "nonut.csv"  # an input of both models missing
    drop = head.index("nut")
    no_nut.write_text("\n".join(",".join(v for i, v in enumerate(r.split(",")) if i != drop)
                                for r in text) + "\n", encoding="ascii")
    _one_line(capsys, EX_DATAERR, "nut", str(fitted.value), str(no_nut), *models)
    fast = d / "fast.csv"  # another period
    assert main(["sim", "--machine", "ballscrew", "--record", str(fast), "--hours", "2",
                 "--period-s", "60"]) == 0
    _one_line(capsys, EX_DATAERR, "sampled every 60 s", str(fitted.value), str(fast), *models)


@pytest.mark.parametrize(("extra", "says"), [
    (["--column", "dx_at_0mm_um"], "--column goes without --slope-model"),
    (["--plot", "x.png"], "--plot goes without --slope-model"),
    (["--probe-every-min", "30"], "--probe-every-min goes without --slope-model"),
    (["--score-from", "100", "--score-until", "50"], "is before --score-from"),
])
def test_options_of_one_column_go_without_the_slope(fitted: Fitted, extra: list[str],
                                                    says: str,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    _one_line(capsys, EX_USAGE, says, str(fitted.value), str(fitted.held), "--slope-model",
              str(fitted.slope), *extra)


def test_without_a_column_or_a_slope_model_replay_says_what_it_needs(
        fitted: Fitted, capsys: pytest.CaptureFixture[str]) -> None:
    _one_line(capsys, EX_USAGE, "--column COLUMN is required", str(fitted.value),
              str(fitted.held))
    _one_line(capsys, EX_USAGE, "--reference-position-mm goes with --slope-model",
              str(fitted.value), str(fitted.held), "--reference-position-mm", "5")


def _docs_blocks() -> list[str]:
    text = (Path(__file__).resolve().parents[3] / "docs" / "calibration.md").read_text(
        encoding="utf-8")
    section = text[text.index("### Along an axis: a value and a slope"):]
    return re.findall(r"```\n(.*?)```", section.replace("\\\n", " "), flags=re.S)


def test_calibration_md_quotes_what_its_commands_print(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """§7's fit commands and its replay, run as written: the table quoted is the one
    replay prints."""
    fits, replay = _docs_blocks()[:2]
    monkeypatch.chdir(tmp_path)
    for line in fits.strip().splitlines():
        assert main(shlex.split(line)[1:]) == 0, line
    commands = [ln.removeprefix("$ ") for ln in replay.splitlines() if ln.startswith("$ ")]
    quoted = [ln for ln in replay.splitlines() if ln and not ln.startswith("$ ")]
    assert len(commands) == 2 and len(quoted) == 9
    for command in commands:
        capsys.readouterr()
        assert main(shlex.split(command)[1:]) == 0, command
    assert [ln.rstrip() for ln in capsys.readouterr().out.splitlines()] == quoted


def test_models_that_do_not_say_take_the_position_asked_else_zero(fitted: Fitted) -> None:
    from compd.infiles import load_model
    from compd.offline.position_replay import LineModelError, check_line_models

    value, slope = load_model(str(fitted.value)), load_model(str(fitted.slope))
    assert check_line_models(value, slope, None) == (0.0, "models")
    for m in (value, slope):  # a model written by hand, or by an older compd fit
        del m.provenance["positions_column"], m.provenance["reference_position_mm"]
    assert check_line_models(value, slope, None) == (0.0, "default")
    assert check_line_models(value, slope, 250.0) == (250.0, "asked")
    slope.provenance["reference_position_mm"] = "0"
    with pytest.raises(LineModelError, match="is not a position"):
        check_line_models(value, slope, None, names=("v.toml", "s.toml"))
    slope.provenance["reference_position_mm"] = 250.0  # one model says, the other does not
    assert check_line_models(value, slope, None) == (250.0, "models")
