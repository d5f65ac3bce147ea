"""The whole calibration recipe on the shop variant of the simulated machine:
sixteen sensors and the spindle speed as candidates, calibrate
on day 1, verify on day 2 (which starts warm), against the shared-denominator
ARX least squares on the best pair of the same search, in the same run."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pytest

from compd.cli import main
from compd.infiles import load_model

SEED = 3


@pytest.fixture(scope="module")
def days(tmp_path_factory: pytest.TempPathFactory,
         shop_record: Callable[[int], Path]) -> tuple[Path, Path]:
    d = tmp_path_factory.mktemp("shop")
    lines = shop_record(SEED).read_text().splitlines()
    head, rows = lines[0], lines[1:]
    half = len(rows) // 2
    day1, day2 = d / "day1.csv", d / "day2.csv"
    day1.write_text("\n".join([head, *rows[:half + 1]]) + "\n")
    day2.write_text("\n".join([head, *rows[half:]]) + "\n")
    return day1, day2


def _json(capsys: pytest.CaptureFixture[str], argv: list[str]) -> dict[str, object]:
    capsys.readouterr()
    assert main(argv) == 0
    doc: dict[str, object] = json.loads(capsys.readouterr().out)
    return doc


def test_inputs_chosen_by_validation_verify_on_the_next_day(
        days: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    day1, day2 = days
    model = tmp_path / "shop.toml"
    fit = _json(capsys, ["fit", str(day1), "--column", "dz_um", "--candidates", "t*_degC",
                         "--candidates", "spindle_rpm", "--max-terms", "3", "-o", str(model),
                         "--json"])
    subsets = fit["subsets"]
    assert isinstance(subsets, list) and len(subsets) > 17
    prov = load_model(model).provenance
    assert 1 <= len(prov["inputs_chosen"]) <= 3 and len(prov["subsets_tried"]) == len(subsets)
    assert prov["structure"] and prov["runners_up"]
    ours = _json(capsys, ["replay", str(model), str(day2), "--column", "dz_um", "--json"])
    assert ours["init"] == "estimate"
    assert float(ours["fit_percent"]) >= 88.0  # type: ignore[arg-type]
    assert float(ours["range_reduction"]) >= 7.0  # type: ignore[arg-type]
    pairs = [s for s in subsets if len(s["inputs"]) == 2]
    best_pair = max(pairs, key=lambda s: s["validation_fit_percent"])["inputs"]
    base_model = tmp_path / "arx.toml"
    terms = [a for ch in best_pair for a in ("--term", ch)]
    _json(capsys, ["fit", str(day1), "--column", "dz_um", *terms, "--structure", "arx",
                   "-o", str(base_model), "--json"])
    base = _json(capsys, ["replay", str(base_model), str(day2), "--column", "dz_um", "--json"])
    assert float(ours["fit_percent"]) > float(base["fit_percent"])  # type: ignore[arg-type]


def test_a_searched_model_with_a_speed_term_is_one_the_daemon_steps(
        days: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Speed enters absolute (relative = false); the model passes `compd check`,
    starts at steady state and round-trips its state like any other."""
    day1, _ = days
    model_path = tmp_path / "speed.toml"
    assert main(["fit", str(day1), "--column", "dz_um", "--term", "t1_degC", "--term",
                 "spindle_rpm", "--orders", "1-2", "-o", str(model_path)]) == 0
    model = load_model(model_path)
    speed = next(t for t in model.terms if t.name == "spindle_rpm")
    assert speed.relative is False and model.reference_channels == {"t1_degC"}
    assert 'relative = false' in model_path.read_text()
    assert main(["check", str(model_path)]) == 0
    sample = {"t1_degC": 25.0, "spindle_rpm": 6000.0}
    model.set_references({"t1_degC": 22.0})
    level = model.steady_state(sample)
    state = model.export_state()
    first = model.step(sample)
    model.import_state(state)
    assert model.step(sample) == first == pytest.approx(level)


def test_term_or_candidates_one_of_the_two(days: tuple[Path, Path],
                                           capsys: pytest.CaptureFixture[str]) -> None:
    day1, _ = days
    out = ["-o", str(day1.parent / "m.toml")]
    assert main(["fit", str(day1), "--column", "dz_um", *out]) == 65
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--candidates" in err
    assert main(["fit", str(day1), "--column", "dz_um", "--candidates", "nope*", *out]) == 65
    assert "matches no column" in capsys.readouterr().err


def test_the_progress_bar_draws_on_stderr_only_when_asked(
        capsys: pytest.CaptureFixture[str]) -> None:
    from compd.offline.fit_search import progress_bar

    assert progress_bar(False) is None
    show = progress_bar(True)
    assert show is not None
    show(3, 10)
    show(10, 10)
    out = capsys.readouterr()
    assert out.out == "" and "3/10 subsets" in out.err and "[" + "#" * 30 + "]" in out.err
