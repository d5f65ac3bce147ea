"""`compd step` labels the value at its span's end as that (with its time),
not as the steady state, and shows the DC gain: with a span capped at 48 h a
slow term is far from it, and the command says so."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from compd.cli import main

#: one first-order term, pole 0.9999 at 60 s: τ ≈ 167 h, DC gain 10 µm/K
SLOW = """[model]
name = "slow"
period_s = 60.0
channels = ["bearing"]

[[terms]]
name = "bearing"
kind = "tf"
inputs = { bearing = 1.0 }
gain = 1.0
a = ["0.001"]
b = ["1.0", "-0.9999"]
"""


@pytest.fixture
def slow(tmp_path: Path) -> Path:
    p = tmp_path / "slow.toml"
    p.write_text(SLOW, encoding="utf-8")
    return p


def test_a_capped_span_is_said_and_the_dc_gain_shown(
        slow: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["step", str(slow)]) == 0
    out = capsys.readouterr().out
    assert out.startswith("span capped at 48 h")
    line = out.splitlines()[1]
    assert "y(48 h, the span's end) = " in line
    assert "DC gain 10 µm/K" in line and "(25.0 % of it)" in line  # 1 - 0.9999^2880 ≈ 0.25


def test_json_carries_the_dc_gain_and_the_cap(slow: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["step", str(slow), "--json"]) == 0
    [term] = json.loads(capsys.readouterr().out)["terms"]
    assert term["dc_gain_um"] == pytest.approx(10.0)
    assert term["span_capped"] is True
    assert term["y_end_um"] == pytest.approx(10.0 * (1 - 0.9999 ** 2881), rel=1e-3)


def test_a_settled_span_is_not_called_capped(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["step", "sp2"]) == 0
    out = capsys.readouterr().out
    assert "capped" not in out and "DC gain 17.647 µm/K" in out


def test_the_figure_labels_the_span_end_and_the_dc_gain(
        slow: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    from matplotlib.axes import Axes

    labels: list[str] = []
    real = Axes.legend

    def spy(self: Axes, *args: object, **kwargs: object) -> object:
        legend = real(self, *args, **kwargs)
        labels.extend(t.get_text() for t in legend.get_texts())
        return legend

    monkeypatch.setattr(Axes, "legend", spy)
    assert main(["step", str(slow), "--plot", str(tmp_path / "s.png")]) == 0
    assert (tmp_path / "s.png").stat().st_size > 0
    assert labels[0].startswith("bearing: ") and labels[0].endswith(" µm/K at 48 h"), labels
    assert labels[1].startswith("bearing: DC gain (steady state) 10 µm/K, 25 % of it"), labels
