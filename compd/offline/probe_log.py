"""Probe records: what `compd refine` reads (the probes a running machine took).

Two kinds, by the file's suffix:

- the daemon's recorder database (``.db``, ``.sqlite``, ``.sqlite3``): its ``probes``
  table, each probe on its sample's clock; the probes the estimator accepted and those
  its gate refused (a real move it was not yet told to follow is evidence too), not
  those refused as faults (no complete cycle, no offset to add);
- a CSV probe log, one row per probe: ``time_s`` (seconds, increasing; or an ISO 8601
  ``time`` column, as a record's), ``measured_um`` (the displacement the probe measured)
  and ``model_um`` (the plain model's prediction at that moment), the recorder's own
  names; every cell a number, read by the records' one CSV reader.

The residual each probe gives is measured − model. A probe whose measured value,
model value or residual lies beyond ±`compd.config.schema.MAX_LIMIT_UM` (10 mm, the
largest offset `compd check` accepts) measured no thermal error: the file is refused
naming its row (the CSV's line, the recorder's ``seq``). A bad file ends in a
`RecordError` naming the file (and the row and column where there is one).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from compd.offline.records import (
    RECORDER_SUFFIXES,
    RecordError,
    file_sha256,
    is_export,
    read_csv_columns,
)

FloatArray = npt.NDArray[np.float64]

#: the CSV probe log's columns
LOG_COLUMNS = ("time_s", "measured_um", "model_um")
#: refusal reasons whose probe still measured the machine (the gate's)
MEASURED_REASONS = ("", "gate")


@dataclass(frozen=True)
class ProbeLog:
    path: str
    sha256: str
    time_s: FloatArray
    residual_um: FloatArray
    left_out: int  # probes in the file not used (faults, no value)


def read_probe_log(path: str | Path) -> ProbeLog:
    """The probes of a recorder database or a CSV probe log (see the module)."""
    if Path(path).suffix.lower() in RECORDER_SUFFIXES:
        return _read_recorder(Path(path))
    return _read_csv(Path(path))


def _read_recorder(p: Path) -> ProbeLog:
    from compd.store.reader import RecorderReader
    from compd.store.schema import RecorderError

    where = str(p)
    try:
        with RecorderReader(p) as reader:
            cols = reader.probes()
    except RecorderError as exc:
        raise RecordError(f"{where}: {exc.reason}") from None
    use = np.isin(cols["reason"], MEASURED_REASONS) & np.isfinite(cols["measured_um"]) \
        & np.isfinite(cols["model_um"]) & np.isfinite(cols["mono_s"])
    seq = cols["seq"][use]
    measured, model = cols["measured_um"][use], cols["model_um"][use]
    _check_bound(measured, model, lambda k: f"{where}: probe seq {int(seq[k])}")
    return ProbeLog(where, file_sha256(p), cols["mono_s"][use], measured - model,
                    int(use.size - np.count_nonzero(use)))


def _read_csv(p: Path) -> ProbeLog:
    """The CSV probe log, parsed by the records' one CSV reader (every cell a number,
    the same refusals), then checked for what a probe log needs."""
    where = str(p)
    header, t_idx, data = read_csv_columns(p, "probe log")
    missing = [c for c in LOG_COLUMNS[1:] if c not in header]
    if missing and is_export(header):
        raise RecordError(f"{where}: an export of the recorder's samples, without the probes' "
                          "measured_um; give refine the recorder database itself")
    if missing:
        raise RecordError(f"{where}: no column(s) {missing} (a probe log has "
                          f"{', '.join(LOG_COLUMNS)}; header {header[:8]})")
    t = data[t_idx]
    back = np.flatnonzero(np.diff(t) <= 0.0)
    if back.size:
        k = int(back[0])
        raise RecordError(f"{where}: row {k + 3}: time {float(t[k + 1])!r} does not follow "
                          f"{float(t[k])!r} (probes in time order)")
    measured, model = data[header.index("measured_um")], data[header.index("model_um")]
    _check_bound(measured, model, lambda k: f"{where}: row {k + 2}")
    return ProbeLog(where, file_sha256(p), t - t[0] if t.size else t, measured - model, 0)


def _check_bound(measured: FloatArray, model: FloatArray, row: Callable[[int], str]) -> None:
    """Refuse the first probe whose measured or model value or residual lies beyond
    ±MAX_LIMIT_UM, naming it by `row(index)` and the value (finite values in)."""
    from compd.config.schema import MAX_LIMIT_UM

    with np.errstate(over="ignore", invalid="ignore"):  # ±1e308 − ∓1e308 is ±inf: beyond
        columns = {"measured_um": measured, "model_um": model, "measured − model": measured - model}
    beyond = {name: ~(np.abs(values) <= MAX_LIMIT_UM) for name, values in columns.items()}
    rows = np.flatnonzero(np.logical_or.reduce(list(beyond.values())))
    if rows.size:
        k = int(rows[0])
        name = next(n for n, b in beyond.items() if b[k])
        raise RecordError(f"{row(k)}: {name} {float(columns[name][k]):g} µm is beyond "
                          f"±{MAX_LIMIT_UM:g} µm (10 mm, the largest offset compd "
                          "accepts): no thermal error a probe measures")


def describe(log: ProbeLog) -> str:
    span = float(log.time_s[-1] - log.time_s[0]) if log.time_s.size else math.nan
    return f"{log.time_s.size} probe(s) over {span / 3600.0:.3g} h"
