"""`compd report`'s content: a model judged on records, as an engineer hands
it on (docs/calibration.md §9).

For each record: its role (calibration when its SHA-256 is one the model's
provenance lists, else held out: the fit never saw it; ``held_out_from_s``
splits a record in two), the replay of the bare model over it (initial state
estimated, as `compd replay` does), the figures per window, and the ISO 230-3
figures: the drift over the run, and the environmental temperature variation
error (ETVE) where the record is an environmental run. For the model: the
structure choice as its provenance holds it, each term's step response on one
scale per input unit, its poles with their time constants, and the
provenance. The page is built by `compd.offline.report_page`.
"""

from __future__ import annotations

import hashlib
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from compd.offline.channel_kind import ChannelKind, channel_kind
from compd.offline.plots import WINDOW_COLOURS, Window
from compd.offline.records import Record
from compd.offline.report_page import Cell, Page, cell
from models.compensation import CompensationModel
from models.quality import CompensationFigures, quality

FloatArray = npt.NDArray[np.float64]

#: a record is drawn with at most this many points per line (every k-th sample);
#: the figures in the tables use every sample
MAX_DRAWN_POINTS = 4000
#: column names that hold the room's temperature (an ETVE test's environment)
_AMBIENT = re.compile(r"ambient|room|environment|hall|air", re.IGNORECASE)
#: a spindle at or below this speed (rpm) is at rest (ISO 230-3's ETVE test)
AT_REST_RPM = 1.0


@dataclass(frozen=True)
class Scored:
    """One window of a record and the model's figures on it."""

    window: Window
    first: int
    end: int
    figures: CompensationFigures
    mae_um: float
    rms_um: float


@dataclass(frozen=True)
class RecordResult:
    record: Record
    role: str
    simulated: FloatArray
    measured: FloatArray
    windows: tuple[Scored, ...]


def record_role(record: Record, provenance: Mapping[str, Any]) -> str:
    """"calibration" when the record's SHA-256 is one the fit read, else
    "held out" (a validation record of the fit, or one it never saw)."""
    hashes = provenance.get("data_sha256s") or [provenance.get("data_sha256")]
    return "calibration" if record.sha256 in hashes else "held out"


def score(record: Record, measured: FloatArray, simulated: FloatArray, role: str,
          held_out_from_s: float | None) -> tuple[Scored, ...]:
    """The record's windows (one, or calibration and held out split at
    `held_out_from_s`) with the figures on each."""
    t = record.time_s
    cuts = [(0, len(record), role)]
    if held_out_from_s is not None and role != "calibration":
        split = int(np.searchsorted(t, held_out_from_s - 1e-9))
        if 0 < split < len(record):
            cuts = [(0, split, "calibration"), (split, len(record), "held out")]
    out = []
    for first, end, name in cuts:
        m, s = measured[first:end], simulated[first:end]
        res = m - s
        stop = float(t[end]) if end < len(record) else float(t[-1])
        out.append(Scored(Window(float(t[first]), stop, name), first, end, quality(m, s),
                          float(np.mean(np.abs(res))), float(np.sqrt(np.mean(res ** 2)))))
    return tuple(out)


def _speed(record: Record) -> FloatArray | None:
    speeds = [v for k, v in record.columns.items() if channel_kind(k) is ChannelKind.SPEED]
    return np.max(np.abs(np.vstack(speeds)), axis=0) if speeds else None


def ambient_column(record: Record, model: CompensationModel) -> str | None:
    """The record's room temperature: a column named like one (ambient, room,
    air, ...), the model's channels first."""
    names = [*[c for c in record.columns if c in model.channels],
             *[c for c in record.columns if c not in model.channels]]
    return next((c for c in names if _AMBIENT.search(c)
                 and channel_kind(c) is ChannelKind.TEMPERATURE), None)


def iso_figures(result: RecordResult, model: CompensationModel) -> dict[str, Any]:
    """ISO 230-3's figures for one record: the drift of δZ from its first
    sample over the run (largest excursion each way, and its range) without
    and with compensation; and, when the spindle is at rest throughout and
    the record has a room temperature, the ETVE (the range of δZ) beside the
    room's variation (ETV, K) and the ETVE left with compensation."""
    rec, m = result.record, result.measured
    drift = m - m[0]
    res = m - result.simulated
    out: dict[str, Any] = {
        "hours": float(rec.time_s[-1] - rec.time_s[0]) / 3600.0,
        "drift_max_um": float(drift.max()), "drift_min_um": float(drift.min()),
        "drift_range_um": float(np.ptp(drift)),
        "drift_at_h": float(rec.time_s[int(np.argmax(np.abs(drift)))]) / 3600.0,
        "residue_range_um": float(np.ptp(res)),
    }
    speed = _speed(rec)
    ambient = ambient_column(rec, model)
    if speed is not None and float(np.max(speed)) > AT_REST_RPM:
        out["etve"] = "not an ETVE run: the spindle turns"
    elif ambient is None:
        out["etve"] = "no room temperature column (ambient, room, air, …)"
    else:
        out["etve"] = None
        out["etve_um"] = float(np.ptp(m))
        out["etv_k"] = float(np.ptp(rec.columns[ambient]))
        out["etve_compensated_um"] = float(np.ptp(res))
        out["ambient"] = ambient
        out["spindle"] = "at rest" if speed is not None else "no speed column: taken at rest"
    return out


def thin(n: int) -> slice:
    """Every k-th sample, k so that at most `MAX_DRAWN_POINTS` are drawn."""
    return slice(None, None, max(1, math.ceil(n / MAX_DRAWN_POINTS)))


def file_sha256(path: str) -> str | None:
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return None


def _pct(x: float) -> str:
    return f"{x:.2f} %"


def summary_rows(results: Sequence[RecordResult]) -> list[list[Cell]]:
    rows = []
    for r in results:
        for w in r.windows:
            q = w.figures
            rows.append([cell(Path(r.record.path).name, css="name"), cell(w.window.label),
                         cell(f"{w.window.start_s / 3600:.3g} … {w.window.end_s / 3600:.3g} h"),
                         cell(w.end - w.first), cell(q.fit_percent, ".2f"), cell(w.mae_um, ".3f"),
                         cell(w.rms_um, ".3f"),
                         cell(f"{q.residue_min_um:.3f} … {q.residue_max_um:.3f}"),
                         cell(q.dpk_um, ".3f"), cell(q.range_reduction, ".2f")])
    return rows


def _runner_rows(prov: Mapping[str, Any]) -> list[list[Cell]]:
    chosen = str(prov.get("structure", ""))
    rows = []
    for entry in prov.get("runners_up", []) or []:
        text = str(entry)
        name, sep, rest = text.partition(": validation ")
        figure = rest.removesuffix(" %") if sep else ""
        is_chosen = bool(sep) and chosen.split(" ", maxsplit=1)[0] == name
        rows.append([cell(name if sep else text, css="chosen" if is_chosen else ""),
                     cell(f"{figure} %" if figure else "—"),
                     cell("chosen" if is_chosen else "")])
    return rows


def _stability(prov: Mapping[str, Any]) -> list[tuple[str, Any]]:
    return [(k, v) for k, v in prov.items() if "stab" in k.lower()]


def validation_section(page: Page, prov: Mapping[str, Any]) -> None:
    page.heading("Validation: how the structure was chosen", anchor="validation")
    if not prov:
        page.note("The model file has no provenance: how it was chosen is not recorded.",
                  "note missing")
        return
    facts = [("structure chosen", prov.get("structure")),
             ("its validation fit", prov.get("validation_fit_percent")),
             ("ARX least-squares baseline fit", prov.get("arx_fit_percent")),
             ("output-error fit", prov.get("oe_fit_percent")),
             ("kind", prov.get("kind")),
             ("inputs chosen by validation", prov.get("inputs_chosen"))]
    page.table(["", "as the provenance holds it"],
               [[cell(k), _value_cell(v, "%" if "fit" in k else "")] for k, v in facts
                if v is not None])
    runners = _runner_rows(prov)
    if runners:
        page.heading("Candidates (runners-up), by validation fit", 3)
        page.table(["structure", "validation fit", ""], runners)
    else:
        page.note("Runners-up: not recorded.", "note missing")
    subsets = prov.get("subsets_tried")
    if subsets:
        page.heading("Input subsets tried", 3)
        page.table(["subset: validation (screen)"], [[cell(s, css="mono")] for s in subsets])
    page.heading("How stable the choice was", 3)
    stab = _stability(prov)
    if stab:
        page.table(["", "as the provenance holds it"],
                   [[cell(k, css="mono"), _value_cell(v)] for k, v in stab])
    else:
        page.note("Stability of the choice: not recorded (this model file's provenance holds "
                  "no stability figure).", "note missing")


def _value_cell(value: Any, unit: str = "") -> Cell:
    if isinstance(value, float) and unit == "%":
        return Cell(_pct(value), True)
    if isinstance(value, (list, tuple)):
        return Cell(", ".join(str(v) for v in value), False, "mono")
    if isinstance(value, dict):
        return Cell("; ".join(f"{k} = {v}" for k, v in value.items()), False, "mono")
    return cell(value)


def provenance_rows(prov: Mapping[str, Any]) -> list[list[Cell]]:
    return [[cell(k, css="mono"), _value_cell(v)] for k, v in prov.items()]


def hash_rows(results: Sequence[RecordResult], prov: Mapping[str, Any]) -> list[list[Cell]]:
    listed = list(prov.get("data_sha256s") or [prov.get("data_sha256")])
    names = list(prov.get("data_files") or [prov.get("data_file")])
    rows = []
    for r in results:
        match = (f"the fit's record {names[listed.index(r.record.sha256)]}"
                 if r.record.sha256 in listed and listed.index(r.record.sha256) < len(names)
                 else "not a record the fit read")
        rows.append([cell(r.record.path, css="mono"), cell(r.record.sha256, css="mono"),
                     cell(match)])
    return rows


def window_legend(page: Page) -> None:
    page.legend([(WINDOW_COLOURS["calibration"], "calibration"),
                 (WINDOW_COLOURS["held out"], "held out")],
                "Shaded in the figures:")

