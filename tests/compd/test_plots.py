"""The replay figure: the lower legend names measured/simulated/residue (it
showed the channel names, `labels` was overwritten by the inputs' legend) and
a one-channel record without a speed column draws (it ended in IndexError)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from compd.cli import main
from compd.offline.plots import replay_figure

LOWER = ("measured δZ", "simulated (model)", "residue (after compensation)")


@pytest.mark.parametrize("inputs", [("bearing", "ambient", "speed_rpm"), ("bearing",),
                                    ("speed_rpm",)])
def test_the_lower_legend_names_the_three_curves(inputs: tuple[str, ...], tmp_path: Path) -> None:
    t = np.arange(100.0)
    upper, lower = replay_figure(
        tmp_path / "f.png", t, {n: 20.0 + t / 50 for n in inputs}, t / 10, t / 11,
        title="t", fit_pct=90.0, dpk_um=1.0)
    assert lower == list(LOWER)
    assert upper == [f"{n} ({'rpm' if 'speed' in n else '°C'})" for n in inputs]
    assert (tmp_path / "f.png").stat().st_size > 0


def test_replay_plots_a_one_channel_model_without_a_speed_column(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    model = tmp_path / "one.toml"
    model.write_text('[model]\nname = "one"\nperiod_s = 1.0\nchannels = ["bearing"]\n\n'
                     '[[terms]]\nname = "spindle"\ninputs = { bearing = 1.0 }\n'
                     'a = ["0.1", "0"]\nb = ["1", "-0.9"]\n', encoding="utf-8")
    rec = tmp_path / "one.csv"
    rec.write_text("time_s,bearing,dz_um\n" + "".join(
        f"{k},{25 + k / 100:.2f},{k / 100:.3f}\n" for k in range(300)), encoding="utf-8")
    figure = tmp_path / "one.png"
    assert main(["replay", str(model), str(rec), "--column", "dz_um", "--plot",
                 str(figure)]) == 0
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "figure:" in capsys.readouterr().out
