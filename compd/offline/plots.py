"""Figures like the papers': a replay (inputs above; measured, simulated and
residual displacement below) and the step response of each term.

matplotlib with the Agg backend (files only, no display); imported only by
the commands that draw.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

import matplotlib as mpl

mpl.use("Agg")

import matplotlib.pyplot as plt
import numpy as np
import numpy.typing as npt
from matplotlib.axes import Axes
from matplotlib.text import Text

from compd.offline.channel_kind import ChannelKind, channel_kind

FloatArray = npt.NDArray[np.float64]


def _rate_axis_label(kinds: set[ChannelKind]) -> str:
    if kinds == {ChannelKind.SPEED}:
        return "spindle speed (rpm)"
    if kinds == {ChannelKind.POWER}:
        return "power"
    return "speed (rpm) / power"


def replay_figure(path: str | Path, time_s: FloatArray, inputs: Mapping[str, FloatArray],
                  measured: FloatArray, simulated: FloatArray, *, title: str,
                  fit_pct: float, dpk_um: float,
                  labels: tuple[str, str, str] = ("measured δZ", "simulated (model)",
                                                  "residue (after compensation)"),
                  adapted: FloatArray | None = None,
                  probes: tuple[FloatArray, FloatArray, npt.NDArray[np.bool_]] | None = None
                  ) -> tuple[list[str], list[str]]:
    """Draw the figure; return the legends' entries (upper, lower) as drawn.

    With `adapted` (`compd replay --probe-every`) the lower panel adds the model
    with the estimator's correction and its residue, and `probes` (times, values,
    accepted) marks each probe: a dot when used, a cross when refused."""
    hours = np.asarray(time_s) / 3600.0
    fig, (top, bottom) = plt.subplots(2, 1, sharex=True, figsize=(10, 7),
                                      gridspec_kw={"height_ratios": [2, 3]})
    kinds = {k: channel_kind(k) for k in inputs}
    temps = {k: v for k, v in inputs.items() if kinds[k] is ChannelKind.TEMPERATURE}
    rates = {k: v for k, v in inputs.items() if kinds[k] is not ChannelKind.TEMPERATURE}
    for name, values in temps.items():
        top.plot(hours, values, lw=1.0, label=f"{name} (°C)")
    top.set_ylabel("temperature (°C)")
    top.grid(True, alpha=0.3)
    # the inputs' legend has names of its own: `labels` stays the lower panel's
    handles, names = top.get_legend_handles_labels()
    if rates:
        right = top.twinx()
        for name, values in rates.items():
            unit = " (rpm)" if kinds[name] is ChannelKind.SPEED else ""
            right.plot(hours, values, lw=0.8, color="0.55", ls="--", label=f"{name}{unit}")
        right.set_ylabel(_rate_axis_label({kinds[k] for k in rates}))
        h2, l2 = right.get_legend_handles_labels()
        handles, names = handles + h2, names + l2
    if handles:
        top.legend(handles, names, loc="upper right", fontsize="small", ncol=2)
    top.set_title("inputs")
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
    bottom.legend(loc="best", fontsize="small")
    bottom.set_title(f"fit {fit_pct:.1f} %, Δpk {dpk_um:.2f} µm "
                     f"(residue {residue.min():.2f} … {residue.max():.2f} µm)")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return [t.get_text() for t in legend_texts(top)], [t.get_text() for t in
                                                       legend_texts(bottom)]


def legend_texts(ax: Axes) -> list[Text]:
    legend = ax.get_legend()
    return list(legend.get_texts()) if legend is not None else []


def step_figure(path: str | Path, time_s: FloatArray, responses: Mapping[str, FloatArray],
                units: Mapping[str, str], *, title: str,
                dc_gains: Mapping[str, float] | None = None) -> None:
    """One panel per term: the response to a unit step of its input, the value
    at the span's end (labelled with its time: not the steady state when the
    span is shorter than the settling) and the DC gain, the steady state."""
    hours = np.asarray(time_s) / 3600.0
    n = max(1, len(responses))
    fig, axes = plt.subplots(n, 1, sharex=True, figsize=(9, 2.6 * n + 0.8), squeeze=False)
    for ax, (name, y) in zip(axes[:, 0], responses.items(), strict=True):
        ax.plot(hours, y, lw=1.4, color="tab:blue")
        end = float(y[-1])
        ax.axhline(end, color="0.5", lw=0.7, ls="--",
                   label=f"at {float(hours[-1]):.3g} h (span end): {end:.4g} µm")
        gain = (dc_gains or {}).get(name)
        if gain is not None and math.isfinite(gain):
            ax.axhline(gain, color="tab:green", lw=0.8, ls=":",
                       label=f"DC gain (steady state): {gain:.4g} µm")
        ax.set_ylabel("δZ (µm)")
        ax.set_title(f"term {name}: step of 1 {units.get(name, 'K')} at t = 0")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize="small")
    axes[-1, 0].set_xlabel("time (h)")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
