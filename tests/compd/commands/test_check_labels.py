"""`compd check`'s printed labels: a zero is labelled |z|, a pole that
alternates sign (negative real part) has no time constant, a time constant is
given in time too, and a DC gain is in the unit of its input (µm/K for a
temperature term, µm/rpm for a speed term), the same on both lines."""

from __future__ import annotations

from pathlib import Path

import pytest

from compd.cli import main

MODEL = """[model]
name = "labels"
period_s = 60.0
channels = ["bearing", "spindle_rpm"]

[[terms]]
name = "bearing"
inputs = { bearing = 1.0 }
a = ["0.1", "0.05"]
b = ["1", "-0.5", "-0.3"]

[[terms]]
name = "speed"
relative = false
inputs = { spindle_rpm = 1.0 }
a = ["0.0001"]
b = ["1", "-0.9"]
"""


def test_zero_pole_and_unit_labels(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    f = tmp_path / "m.toml"
    f.write_text(MODEL, encoding="utf-8")
    assert main(["check", str(f)]) == 0
    out = capsys.readouterr().out
    bearing, speed = out.split("term 'speed'")
    # poles of 1 - 0.5 z^-1 - 0.3 z^-2: 0.852 and -0.352
    poles = next(line for line in bearing.splitlines() if "poles:" in line)
    pos, neg = sorted(poles.split("), "), key=lambda s: "-0.352" in s)
    assert "τ ≈ 6 samples = 6.25 min" in pos
    assert "-0.352" in neg and "τ" not in neg and "alternates sign" in neg
    zeros = next(line for line in bearing.splitlines() if "zeros:" in line)
    assert "|z| = 0.5" in zeros and "|p|" not in zeros
    assert "DC gain: 0.75 µm/K" in bearing and "µm/unit" not in out
    assert "DC gain: 0.001 µm/rpm" in speed
    sens = next(line for line in speed.splitlines() if "sensitivity:" in line)
    assert "µm/rpm" in sens and "µm/K" not in sens
