"""Probe records: what `compd refine` reads (the probes a running machine took).

Two kinds, by the file's suffix:

- the daemon's recorder database (``.db``, ``.sqlite``, ``.sqlite3``): its ``probes``
  table, each probe on its sample's clock; the probes the estimator accepted and those
  its gate refused (a real move it was not yet told to follow is evidence too), not
  those refused as faults (no complete cycle, no offset to add);
- a CSV probe log, one row per probe: ``time_s`` (seconds, increasing), ``measured_um``
  (the displacement the probe measured) and ``model_um`` (the plain model's prediction
  at that moment), the recorder's own names; other columns are ignored.

The residual each probe gives is measured − model. A bad file ends in a
`RecordError` naming the file (and the row and column where there is one).
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from compd.infiles import MAX_RECORD_BYTES, open_input
from compd.offline.records import RECORDER_SUFFIXES, RecordError, _parse_float, file_sha256

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
    return ProbeLog(where, file_sha256(p), cols["mono_s"][use],
                    (cols["measured_um"] - cols["model_um"])[use],
                    int(use.size - np.count_nonzero(use)))


def _read_csv(p: Path) -> ProbeLog:
    where = str(p)
    rows: list[tuple[float, float]] = []
    with open_input(p, "probe log", MAX_RECORD_BYTES) as raw:
        text = io.TextIOWrapper(raw, encoding="utf-8-sig", newline="")
        try:
            reader = csv.reader(text)
            header = [h.strip() for h in next(reader, [])]
            missing = [c for c in LOG_COLUMNS if c not in header]
            if missing:
                raise RecordError(f"{where}: no column(s) {missing} (a probe log has "
                                  f"{', '.join(LOG_COLUMNS)}; header {header[:8]})")
            idx = [header.index(c) for c in LOG_COLUMNS]
            for line_no, row in enumerate(reader, start=2):
                if not row:
                    continue
                if len(row) != len(header):
                    raise RecordError(f"{where}: row {line_no}: {len(row)} cells where the "
                                      f"header has {len(header)}")
                t, m, y = (_parse_float(row[i], where, line_no, c)
                           for i, c in zip(idx, LOG_COLUMNS, strict=True))
                if rows and not t > rows[-1][0]:
                    raise RecordError(f"{where}: row {line_no}: time_s {t!r} does not follow "
                                      f"{rows[-1][0]!r} (probes in time order)")
                rows.append((t, m - y))
        except UnicodeDecodeError:
            raise RecordError(f"{where}: not a text (UTF-8) CSV file") from None
        except csv.Error as exc:
            raise RecordError(f"{where}: not a CSV probe log ({exc})") from None
        except OSError as exc:
            raise RecordError(f"{where}: cannot read the probe log ({exc.strerror})") from None
    data = np.array(rows, dtype=np.float64).reshape(-1, 2)
    if not np.all(np.isfinite(data[:, 1])):  # finite inputs, an overflowing difference
        raise RecordError(f"{where}: a residual measured − model beyond the float range")
    return ProbeLog(where, file_sha256(p), data[:, 0], data[:, 1], 0)


def describe(log: ProbeLog) -> str:
    span = float(log.time_s[-1] - log.time_s[0]) if log.time_s.size else math.nan
    return f"{log.time_s.size} probe(s) over {span / 3600.0:.3g} h"
