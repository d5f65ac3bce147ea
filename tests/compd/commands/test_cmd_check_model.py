"""`compd check` on model files: the report, the JSON shape, exit 78 on bad models."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from compd.cli import main


def test_check_json_shape(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check", "sp2", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    names = [t["name"] for t in report["terms"]]
    assert names == ["spindle", "ambient"]
    for t in report["terms"]:
        assert isinstance(t["poles"], list) and all(len(p) == 2 for p in t["poles"])
        assert isinstance(t["stable"], bool) and t["stable"]
        assert isinstance(t["dc_gain"], float)
        assert isinstance(t["dc_gain_sensitivity"], float)
    assert report["terms"][0]["dc_gain"] == pytest.approx(17.647058823529413)


def test_check_text_reports_cancellation_and_ill_determined_gain(
        capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check", "sp1"]) == 0
    out = capsys.readouterr().out
    assert "cancelled exactly by a zero at z = 1" in out
    assert "NOT determined by the printed digits" in out


def test_unstable_model_exits_78_naming_the_term(tmp_path: Path) -> None:
    f = tmp_path / "unstable.toml"
    f.write_text('[model]\nperiod_s = 1.0\n[[terms]]\nname = "runaway"\n'
                 'inputs = { bearing = 1.0 }\na = ["1"]\nb = ["1", "-1.01"]\n')
    proc = subprocess.run([sys.executable, "-m", "compd", "check", str(f)],
                          capture_output=True, text=True, check=False)
    assert proc.returncode == 78
    assert "runaway" in proc.stderr and "unstable" in proc.stderr
    assert proc.stderr.count("\n") == 1  # one message, no traceback
