"""Figures quoted in README.md and docs/ are the ones the quoted commands
print (the docs do not drift): checked here where it is cheap.

- calibration.md §3: `compd replay sim_machine spectrum.csv --column dz_um`
  (the recipe's spectrum record, seed 7) prints the fit % and range reduction
  quoted there, and §5 judges the model by that same fit %.
- The demo's figures are quoted alike in README.md and calibration.md, and
  are the lockstep run's (`test_e2e_protocols`, deterministic).
- protocols.md's status table: the value the pure cycle sends when it finds
  a foreign offset in the controller.
- adaptation.md speaks to users, not of the request that asked for it.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from compd.cli import main
from compd.core.output import Status
from tests.compd.conftest import RecipePlant
from tests.compd.core.cycle_helpers import samples
from tests.compd.core.test_cycle_foreign import _heated
from tests.compd.runtime.test_e2e_protocols import RANGE_REDUCTION

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"


def _read(name: str) -> str:
    return (ROOT / name).read_text(encoding="utf-8")


def test_calibration_md_quotes_what_its_recipe_prints(recipe_plant: RecipePlant,
                                                     tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    """calibration.md §3's commands, run as written: the records and the fit
    (shared with the session, `recipe_plant`), then the spectrum record."""
    spectrum = str(tmp_path / "spectrum.csv")
    plant = str(recipe_plant.plant)
    assert main(["sim", "--record", spectrum, "--program", "spectrum", "--period-s", "60",
                 "--seed", "7"]) == 0
    fit_out = recipe_plant.fit_out
    capsys.readouterr()
    text = _read("docs/calibration.md")
    calibration = re.search(r"model \(replayed as the daemon steps it, initial state "
                            r"estimated\): fit ([\d.]+) %", fit_out)
    assert calibration is not None and calibration.group(0) in text
    figures = {}
    for model in (plant, "sim_machine"):
        assert main(["replay", model, spectrum, "--column", "dz_um", "--json"]) == 0
        doc = json.loads(capsys.readouterr().out)
        figures[model] = (doc["fit_percent"], doc["range_reduction"])
    fit, reduction = figures[plant]
    assert f"fit {fit:.2f} %, " in text and f"range reduction {reduction:.2f}-fold" in text
    fit_b, reduction_b = figures["sim_machine"]
    flat = " ".join(text.split())
    assert f"fit {fit_b:.2f} %, range reduction {reduction_b:.2f}-fold" in flat
    # §5 judges the model by the same calibration and verification figures
    judged = re.search(r"here ([\d.]+) % on\s+calibration against ([\d.]+) % on the spectrum",
                       text)
    assert judged is not None
    assert float(judged.group(1)) == round(float(calibration.group(1)), 1)
    assert float(judged.group(2)) == round(fit, 1)


_DEMO = re.compile(r"range ([\d.]+) µm\s+→\s+([\d.]+) µm, a (\d+)x reduction, fit\s+([\d.]+) %")


def test_the_demo_figures_agree_across_the_docs() -> None:
    quoted = {name: _DEMO.findall(_read(name).replace("\n", " "))
              for name in ("README.md", "docs/calibration.md")}
    assert all(len(v) == 1 for v in quoted.values()), quoted
    assert quoted["README.md"] == quoted["docs/calibration.md"]
    [(_, _, fold, fit)] = quoted["README.md"]
    assert float(fold) == pytest.approx(RANGE_REDUCTION, abs=0.5)
    assert float(fit) == pytest.approx(92.9, abs=0.05)


def test_protocols_md_gives_the_status_of_a_foreign_read_back() -> None:
    cycle, clock, _ = _heated()
    t = clock.tick()
    status = cycle.plan(t, samples(t, 22.0), -50.0).status
    names = " + ".join(f.name for f in Status if f and f & status and f.name)
    row = f"| {int(status)} | {names} |"
    assert row in _read("docs/protocols.md"), row


def test_adaptation_md_does_not_speak_of_the_issue() -> None:
    text = _read("docs/adaptation.md")
    assert "the issue" not in text.lower()
