"""The report's own figure: ISO 230-3's drift over the run, one panel per
record, without compensation (δZ from its first sample) and with it (the
residue from its first sample), the room temperature beside an ETVE run's."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from matplotlib.figure import Figure

from compd.offline.plots import plain
from compd.offline.report import RecordResult, thin


def build_drift_figure(results: Sequence[RecordResult],
                       iso: Sequence[Mapping[str, Any]]) -> Figure:
    n = len(results)
    fig = Figure(figsize=(11, 2.8 * n + 0.6), layout="constrained")
    axes = fig.subplots(n, 1, squeeze=False)[:, 0]
    for ax, r, fig_iso in zip(axes, results, iso, strict=True):
        step = thin(len(r.record))
        hours = r.record.time_s[step] / 3600.0
        drift = (r.measured - r.measured[0])[step]
        res = r.measured - r.simulated
        ax.plot(hours, drift, lw=1.0, color="tab:blue",
                label=f"without compensation: {fig_iso['drift_range_um']:.2f} µm range")
        ax.plot(hours, (res - res[0])[step], lw=1.0, color="tab:red",
                label=f"with compensation: {fig_iso['residue_range_um']:.2f} µm range")
        for level in (fig_iso["drift_max_um"], fig_iso["drift_min_um"]):
            ax.axhline(level, color="tab:blue", lw=0.6, ls=":")
        ax.axhline(0.0, color="0.3", lw=0.6)
        ax.set_ylabel("δZ drift (µm)")
        ax.grid(True, alpha=0.3)
        handles, names = ax.get_legend_handles_labels()
        twin = False
        if fig_iso.get("etve") is None and "ambient" in fig_iso:
            right = ax.twinx()
            room = r.record.columns[fig_iso["ambient"]][step]
            right.plot(hours, room, lw=0.8, color="0.5", ls="--",
                       label=plain(f"{fig_iso['ambient']} (°C): ETV {fig_iso['etv_k']:.2f} K"))
            right.set_ylabel("room (°C)")
            h2, l2 = right.get_legend_handles_labels()
            handles, names = handles + h2, names + l2
            twin = True
        ax.legend(handles, names, loc="upper left", bbox_to_anchor=(1.10 if twin else 1.01, 1.0),
                  fontsize="small", borderaxespad=0.0)
        ax.set_title(plain(f"{Path(r.record.path).name} ({r.role})"), fontsize="medium")
    axes[-1].set_xlabel("time (h)")
    fig.suptitle("drift of δZ over the run (ISO 230-3)")
    for ax in axes:
        ax.set_xlim(left=0.0)
    return fig

