"""The daemon's recorder as a table for a historian or a spreadsheet.

`recorder_table(path, since, until)` reads a recorder database (through
`compd.infiles` and `compd.runtime.recorder.read_samples`) and keeps the rows
whose wall-clock stamp lies in [since, until). Columns, in this order:
``time`` (ISO 8601 UTC of the wall clock), ``wall_s`` (Unix seconds),
``mono_s`` (machine seconds since the daemon started), ``seq``, ``cycle``,
``state``, ``valid``, ``offset_um`` (written and confirmed), ``model_um``,
one column per channel, ``valid.<channel>`` and ``contribution.<term>``.
Missing numbers are empty CSV cells and Parquet nulls.

`write_csv` writes RFC 4180 CSV; `write_parquet` needs pyarrow
(``pip install 'compd[parquet]'``).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, Any

import numpy as np
import numpy.typing as npt

from compd.infiles import MAX_RECORDER_BYTES, check_input

_FIRST = ("wall_s", "mono_s", "seq", "cycle", "state", "valid", "offset_um", "model_um")
_DROP = ("time_s",)  # the same as mono_s


class ExportError(Exception):
    """The recorder cannot be exported as asked (the message says why)."""


@dataclass(frozen=True)
class Table:
    """Columns of equal length, in export order; ``time`` first."""

    columns: dict[str, npt.NDArray[Any]]

    def __len__(self) -> int:
        return len(self.columns["time"])


def parse_when(text: str) -> float:
    """ISO 8601 date or date-time as Unix seconds (UTC when no offset is given)."""
    try:
        when = datetime.fromisoformat(text.strip())
    except ValueError:
        raise ValueError(f"{text!r} is not an ISO 8601 date or time "
                         "(e.g. 2026-11-23 or 2026-11-23T06:00:00+01:00)") from None
    if when.tzinfo is None:
        when = when.replace(tzinfo=UTC)
    return when.timestamp()


def _iso(wall_s: float) -> str:
    """The wall time as ISO 8601; empty when missing or no date at all (a
    corrupt row's 1e308 s is past year 9999: no datetime holds it)."""
    if not math.isfinite(wall_s):
        return ""
    try:
        return datetime.fromtimestamp(wall_s, UTC).isoformat(timespec="milliseconds")
    except (OverflowError, OSError, ValueError):
        return ""


def recorder_table(path: str | Path, since: float | None = None,
                   until: float | None = None) -> Table:
    from compd.runtime.recorder import RecorderError, read_samples

    check_input(path, "recorder database", MAX_RECORDER_BYTES)
    try:
        cols = read_samples(Path(path))
    except RecorderError as exc:
        raise ExportError(f"{path}: {exc.reason}") from None
    except (ValueError, TypeError, AttributeError, KeyError, OverflowError,
            RecursionError) as exc:  # JSON nested without end, too
        raise ExportError(f"{path}: corrupt recorder rows ({type(exc).__name__}); not a "
                          "recorder compd wrote") from None
    wall = np.asarray(cols["wall_s"], dtype=np.float64)
    keep = np.ones(wall.size, dtype=bool)
    if since is not None:
        keep &= wall >= since
    if until is not None:
        keep &= wall < until
    names = [*_FIRST, *(n for n in cols if n not in _FIRST and n not in _DROP)]
    out: dict[str, npt.NDArray[Any]] = {
        "time": np.array([_iso(w) for w in wall[keep]], dtype=object)}
    for name in names:
        out[name] = np.asarray(cols[name])[keep]
    return Table(out)


def _cell(value: Any) -> str:
    if isinstance(value, (bool, np.bool_)):
        return "1" if value else "0"
    if isinstance(value, (float, np.floating)):
        return repr(float(value)) if math.isfinite(value) else ""
    return str(value)


def write_csv(table: Table, out: IO[str]) -> None:
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(list(table.columns))
    cols = list(table.columns.values())
    for i in range(len(table)):
        writer.writerow([_cell(c[i]) for c in cols])


def write_parquet(table: Table, path: Path) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    arrays = {}
    for name, col in table.columns.items():
        if col.dtype.kind == "f":
            arrays[name] = pa.array(col, mask=~np.isfinite(col), type=pa.float64())
        else:
            arrays[name] = pa.array(col.tolist())
    pq.write_table(pa.table(arrays), path)
