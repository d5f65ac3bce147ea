"""The replay figure: the lower legend names measured/simulated/residue (it
showed the channel names, `labels` was overwritten by the inputs' legend) and
a one-channel record without a speed column draws (it ended in IndexError)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from compd.cli import main
from compd.offline.plots import legend_texts, replay_figure

LOWER = ("measured δZ", "simulated (model)", "residue (after compensation)")


@pytest.mark.parametrize("inputs", [("bearing", "ambient", "spindle_rpm"), ("bearing",),
                                    ("spindle_rpm",)])
def test_the_lower_legend_names_the_three_curves(inputs: tuple[str, ...], tmp_path: Path) -> None:
    t = np.arange(100.0)
    upper, lower = replay_figure(
        tmp_path / "f.png", t, {n: 20.0 + t / 50 for n in inputs}, t / 10, t / 11,
        title="t")
    assert lower == list(LOWER)
    assert upper == [f"{n} ({'rpm' if 'rpm' in n else '°C'})" for n in inputs]
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


def _overlaps(a: object, b: object) -> bool:
    from matplotlib.transforms import BboxBase

    assert isinstance(a, BboxBase) and isinstance(b, BboxBase)
    return bool(a.x0 < b.x1 and b.x0 < a.x1 and a.y0 < b.y1 and b.y0 < a.y1)


def _legends_clear_of_axes(fig: object) -> None:
    """No legend lies over any axis's plotting area, and each is inside the figure."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    assert isinstance(fig, Figure)
    canvas = FigureCanvasAgg(fig)
    canvas.draw()  # type: ignore[no-untyped-call]
    renderer = canvas.get_renderer()  # type: ignore[no-untyped-call]
    whole = fig.bbox
    for ax in fig.axes:
        legend = ax.get_legend()
        if legend is None:
            continue
        box = legend.get_window_extent(renderer)
        assert whole.x0 <= box.x0 and box.x1 <= whole.x1 + 0.5, (box, whole)
        for other in fig.axes:
            assert not _overlaps(box, other.get_window_extent(renderer)), (ax.get_title(), box)


def test_a_scored_window_is_titled_with_its_own_figures_and_shaded_outside() -> None:
    """`--score-from`: the title's Δpk and residue range are the scored rows'
    alone (the whole record's residue range sat beside the window's Δpk), the
    rows not scored are shaded and named, and the legends cover no curve."""
    from compd.offline.plots import build_replay_figure

    t = np.arange(0.0, 10 * 3600.0 + 1, 60.0)
    measured = np.where(t > 7 * 3600, 20.0, 0.0) + t / 3600
    simulated = t / 3600
    simulated[:60] += 12.0  # a large residue before the scored window only
    fig = build_replay_figure(t, {"bearing": 20 + t / 7200, "spindle_rpm": t * 0 + 9000},
                              measured, simulated, title="t", scored=(120, len(t)))
    title = fig.axes[1].get_title()
    assert title.startswith("scored 2 … 10 h: ")
    assert "(residue 0.00 … 20.00 µm)" in title and "Δpk 20.00 µm" in title
    assert "-12" not in title
    lower = [x.get_text() for x in legend_texts(fig.axes[1])]
    assert "not scored" in lower
    _legends_clear_of_axes(fig)


def test_the_step_figure_puts_opposing_terms_on_one_scale() -> None:
    """+30 and −15 µm/K terms on one µm/K axis (each term had its own axis and
    scale), labelled per kelvin, the span's end a point, not a line drawn over
    the DC gain."""
    from compd.offline.plots import build_step_figure

    t = np.arange(0.0, 20 * 3600.0, 60.0)
    responses = {"bearing": 30.0 * (1 - np.exp(-t / 3600)),
                 "ambient": -15.0 * (1 - np.exp(-t / 7200)),
                 "speed": 1e-3 * (1 - np.exp(-t / 1800))}
    fig = build_step_figure(t, responses, {"bearing": "K", "ambient": "K", "speed": "rpm"},
                            title="t", dc_gains={"bearing": 30.0, "ambient": -15.0,
                                                 "speed": 1e-3})
    temp, speed = fig.axes
    assert temp.get_ylabel() == "δZ per K (µm/K)" and speed.get_ylabel() == "δZ per rpm (µm/rpm)"
    lo, hi = temp.get_ylim()
    assert lo < -15.0 and hi > 30.0
    names = [x.get_text() for x in legend_texts(temp)]
    assert [n.split(":")[0] for n in names] == ["bearing", "bearing", "ambient", "ambient"]
    horizontal = [ln for ln in temp.get_lines()
                  if len(set(np.asarray(ln.get_ydata(), dtype=float))) == 1
                  and np.asarray(ln.get_xdata()).size == 2]
    levels = sorted(float(np.asarray(ln.get_ydata(), dtype=float)[0]) for ln in horizontal)
    assert levels == [-15.0, 0.0, 30.0]
    _legends_clear_of_axes(fig)
