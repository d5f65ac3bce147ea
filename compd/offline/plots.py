"""Figures like the papers': a replay (inputs above; measured, simulated and
residual displacement below) and the step response of each term.

matplotlib's object API (a `Figure` of its own, no pyplot state), files only,
no display; imported only by the commands that draw. `build_*` return the
figure (the report embeds it as SVG, the tests inspect it), `*_figure` write
it to a file whose suffix says the format. Legends stand beside the axes,
never over a curve.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import numpy as np
import numpy.typing as npt
from matplotlib.artist import Artist
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.text import Text

from compd.offline.channel_kind import ChannelKind, channel_kind

FloatArray = npt.NDArray[np.float64]

#: colours of the marked windows of a record
WINDOW_COLOURS = {"calibration": "#cfe3f7", "held out": "#fbe3c4", "not scored": "#dddddd"}


@dataclass(frozen=True)
class Window:
    """A span of a record's time (seconds) shaded in a figure, with its name
    (one of `WINDOW_COLOURS`' keys, or any text in grey)."""

    start_s: float
    end_s: float
    label: str


def plain(text: str) -> str:
    """`text` drawn as it is: a dollar sign from a file (a column, a model name)
    would start matplotlib's math mode, and an odd number of them fails the draw."""
    return text.replace("$", r"\$")


def _rate_axis_label(kinds: set[ChannelKind]) -> str:
    if kinds == {ChannelKind.SPEED}:
        return "spindle speed (rpm)"
    if kinds == {ChannelKind.POWER}:
        return "power"
    return "speed (rpm) / power"


def _shade(axes: Sequence[Axes], windows: Sequence[Window]) -> None:
    """Shade each window on every axis; the first axis carries one legend
    entry per window name."""
    named: set[str] = set()
    for w in windows:
        colour = WINDOW_COLOURS.get(w.label, "#e4e4e4")
        for i, ax in enumerate(axes):
            label = w.label if i == len(axes) - 1 and w.label not in named else None
            ax.axvspan(w.start_s / 3600.0, w.end_s / 3600.0, color=colour, alpha=0.6, lw=0,
                       zorder=0, label=label)
        named.add(w.label)
        for ax in axes:
            for edge in (w.start_s, w.end_s):
                ax.axvline(edge / 3600.0, color="0.45", lw=0.7, ls=":", zorder=1)


def _legend_beside(ax: Axes, handles: list[Artist] | None = None,
                   names: list[str] | None = None, *, past_twin: bool = False) -> None:
    """The axis's legend outside its right edge (past a twin axis's labels)."""
    anchor = (1.10 if past_twin else 1.01, 1.0)
    if handles is None:
        handles, names = ax.get_legend_handles_labels()
    ax.legend(handles, names or [], loc="upper left", bbox_to_anchor=anchor, fontsize="small",
              borderaxespad=0.0)


def build_replay_figure(time_s: FloatArray, inputs: Mapping[str, FloatArray],
                        measured: FloatArray, simulated: FloatArray, *, title: str,
                        labels: tuple[str, str, str] = ("measured δZ", "simulated (model)",
                                                        "residue (after compensation)"),
                        adapted: FloatArray | None = None,
                        probes: tuple[FloatArray, FloatArray, npt.NDArray[np.bool_]]
                        | None = None,
                        scored: tuple[int, int] | None = None,
                        windows: Sequence[Window] = ()) -> Figure:
    """The replay figure. `scored` (first, end) are the rows the figures are
    computed on: the lower panel's title gives fit %, Δpk and the residue's
    range on those rows alone, and the rows outside are shaded "not scored".
    `windows` shades more spans (calibration, held out). With `adapted`
    (`compd replay --probe-every-min`) the lower panel adds the model with the
    estimator's correction and its residue, and `probes` (times, values,
    accepted) marks each probe: a dot when used, a cross when refused."""
    from models.quality import quality

    hours = np.asarray(time_s) / 3600.0
    fig = Figure(figsize=(11, 7), layout="constrained")
    top, bottom = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [2, 3]})
    kinds = {k: channel_kind(k) for k in inputs}
    temps = {k: v for k, v in inputs.items() if kinds[k] is ChannelKind.TEMPERATURE}
    rates = {k: v for k, v in inputs.items() if kinds[k] is not ChannelKind.TEMPERATURE}
    for name, values in temps.items():
        top.plot(hours, values, lw=1.0, label=f"{plain(name)} (°C)")
    top.set_ylabel("temperature (°C)")
    top.grid(True, alpha=0.3)
    # the inputs' legend has names of its own: `labels` stays the lower panel's
    handles, names = top.get_legend_handles_labels()
    if rates:
        right = top.twinx()
        for name, values in rates.items():
            unit = " (rpm)" if kinds[name] is ChannelKind.SPEED else ""
            right.plot(hours, values, lw=0.8, color="0.55", ls="--", label=f"{plain(name)}{unit}")
        right.set_ylabel(_rate_axis_label({kinds[k] for k in rates}))
        h2, l2 = right.get_legend_handles_labels()
        handles, names = handles + h2, names + l2
    if handles:
        _legend_beside(top, handles, names, past_twin=bool(rates))
    top.set_title("inputs")
    n = len(hours)
    first, end = scored if scored is not None else (0, n)
    marks = list(windows)
    if first > 0:
        marks.append(Window(float(time_s[0]), float(time_s[first]), "not scored"))
    if end < n:
        marks.append(Window(float(time_s[end - 1]), float(time_s[-1]), "not scored"))
    _shade([top, bottom], marks)
    residue = np.asarray(measured) - np.asarray(simulated)
    bottom.plot(hours, measured, lw=0.8, color="tab:blue", label=labels[0])
    bottom.plot(hours, simulated, lw=1.4, color="tab:orange", label=labels[1])
    bottom.plot(hours, residue, lw=0.8, color="tab:red", label=labels[2])
    if adapted is not None:
        bottom.plot(hours, adapted, lw=1.2, color="tab:green", label="adapted (model + bias)")
        bottom.plot(hours, np.asarray(measured) - adapted, lw=0.8, color="tab:purple",
                    label="residue with adaptation")
    if probes is not None:
        t_p, z_p, used = probes
        h_p = np.asarray(t_p) / 3600.0
        bottom.plot(h_p[used], z_p[used], "o", ms=4, color="black", label="probe (used)")
        if not used.all():
            bottom.plot(h_p[~used], z_p[~used], "x", ms=6, color="black",
                        label="probe (refused)")
    bottom.axhline(0.0, color="0.3", lw=0.6)
    bottom.set_xlabel("time (h)")
    bottom.set_ylabel("Z displacement (µm)")
    bottom.grid(True, alpha=0.3)
    _legend_beside(bottom)
    q = quality(np.asarray(measured)[first:end], np.asarray(simulated)[first:end])
    res = residue[first:end]
    where = (f"scored {hours[first]:.3g} … {hours[end - 1]:.3g} h: "
             if (first, end) != (0, n) else "")
    bottom.set_title(f"{where}fit {q.fit_percent:.1f} %, Δpk {q.dpk_um:.2f} µm "
                     f"(residue {res.min():.2f} … {res.max():.2f} µm)")
    fig.suptitle(plain(title))
    return fig


def save_figure(fig: Figure, target: str | Path | IO[bytes], fmt: str | None = None) -> None:
    """Write `fig` (the format from the suffix, or `fmt` for a stream)."""
    fig.savefig(target, dpi=110, format=fmt)


def replay_figure(path: str | Path, time_s: FloatArray, inputs: Mapping[str, FloatArray],
                  measured: FloatArray, simulated: FloatArray, *, title: str,
                  labels: tuple[str, str, str] = ("measured δZ", "simulated (model)",
                                                  "residue (after compensation)"),
                  adapted: FloatArray | None = None,
                  probes: tuple[FloatArray, FloatArray, npt.NDArray[np.bool_]] | None = None,
                  scored: tuple[int, int] | None = None,
                  ) -> tuple[list[str], list[str]]:
    """Write `build_replay_figure`'s figure to `path`; return the legends'
    entries (upper, lower) as drawn."""
    fig = build_replay_figure(time_s, inputs, measured, simulated, title=title, labels=labels,
                              adapted=adapted, probes=probes, scored=scored)
    save_figure(fig, path)
    top, bottom = fig.axes[:2]
    return ([t.get_text() for t in legend_texts(top)],
            [t.get_text() for t in legend_texts(bottom)])


def legend_texts(ax: Axes) -> list[Text]:
    legend = ax.get_legend()
    return list(legend.get_texts()) if legend is not None else []


def build_step_figure(time_s: FloatArray, responses: Mapping[str, FloatArray],
                      units: Mapping[str, str], *, title: str,
                      dc_gains: Mapping[str, float] | None = None) -> Figure:
    """Every term's response to one unit step of its input on one axis per
    input unit (all temperature terms on one µm/K scale, so that terms that
    oppose are seen to), each with its DC gain (the steady state, dotted, in
    the term's colour) and a dot at the span's end; the legend beside the
    axis says both values."""
    hours = np.asarray(time_s) / 3600.0
    groups: dict[str, list[str]] = {}
    for name in responses:
        groups.setdefault(units.get(name, "K"), []).append(name)
    n = max(1, len(groups))
    fig = Figure(figsize=(11, 3.4 * n + 0.6), layout="constrained")
    axes = fig.subplots(n, 1, sharex=True, squeeze=False)[:, 0]
    colours = [f"C{i}" for i in range(10)]
    for ax, (unit, names) in zip(axes, groups.items(), strict=False):
        for i, name in enumerate(names):
            y = responses[name]
            colour = colours[i % len(colours)]
            end = float(y[-1])
            gain = (dc_gains or {}).get(name)
            share = (f", {100.0 * end / gain:.0f} % of it"
                     if gain is not None and math.isfinite(gain) and gain != 0.0 else "")
            ax.plot(hours, y, lw=1.6, color=colour,
                    label=f"{plain(name)}: {end:.4g} µm/{unit} at {float(hours[-1]):.3g} h")
            ax.plot([hours[-1]], [end], "o", ms=4, color=colour)
            if gain is not None and math.isfinite(gain):
                ax.axhline(gain, color=colour, lw=0.9, ls=":",
                           label=f"{plain(name)}: DC gain (steady state) {gain:.4g} "
                                 f"µm/{unit}{share}")
        ax.axhline(0.0, color="0.3", lw=0.6)
        ax.set_ylabel(plain(f"δZ per {unit} (µm/{unit})"))
        ax.set_title(plain(f"response to a step of 1 {unit} at t = 0"))
        ax.grid(True, alpha=0.3)
        _legend_beside(ax)
    axes[-1].set_xlabel("time (h)")
    fig.suptitle(plain(title))
    return fig


def step_figure(path: str | Path, time_s: FloatArray, responses: Mapping[str, FloatArray],
                units: Mapping[str, str], *, title: str,
                dc_gains: Mapping[str, float] | None = None) -> None:
    """Write `build_step_figure`'s figure to `path`."""
    save_figure(build_step_figure(time_s, responses, units, title=title, dc_gains=dc_gains),
                path)
