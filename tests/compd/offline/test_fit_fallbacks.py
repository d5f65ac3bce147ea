"""`compd fit` writes a fallback model for the loss of each input, fitted and
validated the same way on the same record, into the model file; `--no-fallbacks`
writes none."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from compd.cli import main
from compd.infiles import load_model
from tests.compd.offline.records_gen import make_record


@pytest.fixture(scope="module")
def sp3_record(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("sp3fb")
    make_record(d / "cal.csv", "sp3", hours=4, seed=3)
    return d / "cal.csv"


def test_fit_writes_a_fallback_per_input(sp3_record: Path, tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "m.toml"
    assert main(["fit", str(sp3_record), "--column", "dz_um", "--term", "spindle=bearing",
                 "--term", "ambient", "--orders", "1-2", "-o", str(out), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    model = load_model(out)  # what the daemon loads: one file, fallbacks inside
    assert sorted(model.fallbacks) == sorted(result["fallbacks"])
    assert "bearing" in model.fallbacks  # the ambient term alone stands in for the bearing
    for lost, fb in model.fallbacks.items():
        assert lost not in fb.channels and fb.channels < model.channels
        assert fb.provenance["lost"] == lost
        assert fb.period_s == model.period_s
    # the bearing carries the heat: the model without it validates clearly worse
    figures = result["fallbacks"]
    assert figures["bearing"]["validation_fit_percent"] < result["terms"][0]["selection"][
        "validation_fit_percent"]
    assert "[[fallback]]" in out.read_text()


def test_no_fallbacks_writes_none(sp3_record: Path, tmp_path: Path) -> None:
    out = tmp_path / "m.toml"
    assert main(["fit", str(sp3_record), "--column", "dz_um", "--term", "spindle=bearing",
                 "--term", "ambient", "--orders", "1-2", "-o", str(out),
                 "--no-fallbacks"]) == 0
    assert load_model(out).fallbacks == {}
