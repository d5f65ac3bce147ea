"""`compd fit --structure …` on records of the papers' SP3 model: the
printed choice, a forced structure, held-out records instead of folds."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from compd.cli import main
from compd.infiles import load_model
from tests.compd.offline.records_gen import make_record


@pytest.fixture(scope="module")
def sp3(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    d = tmp_path_factory.mktemp("sp3s")
    make_record(d / "cal.csv", "sp3", hours=3, seed=4)
    make_record(d / "ver.csv", "sp3", hours=3, seed=5)
    return d / "cal.csv", d / "ver.csv"


def test_the_choice_is_printed_with_its_runners_up(sp3: tuple[Path, Path], tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "auto.toml"
    assert main(["fit", str(sp3[0]), "--column", "dz_um", "--term", "spindle=bearing",
                 "--term", "ambient", "--orders", "1-2", "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "forward validation (each block predicted from the rows before it), 4 folds" in text
    for name in ("arx", "shared-oe", "ridge", "per-term-oe", "textbook"):
        assert f"    {name}" in text
    prov = load_model(out).provenance
    assert len(prov["runners_up"]) == 5 and prov["validation_fit_percent"] > 90.0
    # how stable the choice was: printed, and in the provenance for a report
    assert "  stability of the choice: " in text and "resampled draws of 8 held-out blocks" in text
    assert 0.0 <= prov["choice_stability"] <= 1.0
    assert prov["choice_stability_text"][0].startswith("stability of the choice: ")


def test_a_forced_structure_and_held_out_records(sp3: tuple[Path, Path], tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "per_term.toml"
    assert main(["fit", str(sp3[0]), "--column", "dz_um", "--term", "spindle=bearing",
                 "--term", "ambient", "--orders", "1-2", "--structure", "per-term-oe",
                 "--validation-record", str(sp3[1]), "-o", str(out), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    sel = doc["terms"][0]["selection"]
    assert sel["structure"] == "per-term-oe" and sel["validation"] == "held-out records"
    assert {c["structure"] for c in sel["candidates"]} == {"arx", "per-term-oe"}
    model = load_model(out)
    assert model.provenance["validation_records"] == [str(sp3[1])]
    dens = [t.dynamics.den for t in model.terms]  # type: ignore[union-attr]
    assert dens[0] != dens[1]  # one denominator per term
    with pytest.raises(SystemExit) as refused:  # bounded by the parser
        main(["fit", str(sp3[0]), "--column", "dz_um", "--term", "bearing", "--folds", "1"])
    assert refused.value.code == 64
    assert "--folds: must be 2" in capsys.readouterr().err
