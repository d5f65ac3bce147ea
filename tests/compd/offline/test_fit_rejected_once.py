"""`compd fit` names a rejected candidate structure once: in the table of
candidates, with its reason; the notes below the table do not say it again."""

from __future__ import annotations

from pathlib import Path

import pytest

from compd.cli import main

RECORD = Path(__file__).resolve().parents[2] / "data" / "fl_thermal" / "calibration.csv"


def test_a_rejected_structure_is_one_line(tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    """On the real record, ch3 on t4 and t6: per-term-oe has a pole at the unit circle
    and is rejected; that reason is printed on one line, not two."""
    model = tmp_path / "m.toml"
    assert main(["fit", str(RECORD), "--column", "ch3_um", "--term", "t4_degC", "--term",
                 "t6_degC", "-o", str(model)]) == 0
    out = capsys.readouterr().out
    rejected = [line for line in out.splitlines() if "rejected:" in line]
    assert len(rejected) == 1, out
    assert rejected[0].lstrip().startswith("per-term-oe") and "near the unit circle" in rejected[0]
