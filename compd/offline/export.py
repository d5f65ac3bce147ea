"""The daemon's recorder as a table for a historian or a spreadsheet, streamed.

`Export(path, since, until)` opens a recorder database (`compd.store.reader`)
and yields the rows whose wall-clock stamp lies in [since, until) a batch at a
time, so that a month's recorder is written in the memory of one batch.
Columns, in this order: ``time`` (ISO 8601 UTC of the wall clock), ``wall_s``
(Unix seconds), ``mono_s`` (machine seconds since the daemon started), ``seq``,
``cycle``, ``state``, ``valid``, ``offset_um`` (written and confirmed),
``model_um``, one column per channel, ``valid.<channel>`` and
``contribution.<term>``. Missing numbers are empty CSV cells and Parquet nulls.

`write_csv` writes RFC 4180 CSV; `write_parquet` needs pyarrow
(``pip install 'compd[parquet]'``), one row group per batch.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, Any

import numpy as np
import numpy.typing as npt

from compd.store.reader import RecorderReader
from compd.store.schema import RecorderError

_FIRST = ("wall_s", "mono_s", "seq", "cycle", "state", "valid", "offset_um", "model_um")
_DROP = ("time_s",)  # the same as mono_s


class ExportError(Exception):
    """The recorder cannot be exported as asked (the message says why)."""


@dataclass(frozen=True)
class Table:
    """One batch: columns of equal length, in export order; ``time`` first."""

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


#: rows per batch of an export (one Parquet row group): ~10 MB of parsed rows
EXPORT_BATCH_ROWS = 8192


class Export:
    """The rows of a recorder in a window, as batches of export columns. Use as a
    context manager; `names` is the column order; `rows` counts what was yielded."""

    def __init__(self, path: str | Path, since: float | None = None,
                 until: float | None = None, *, batch_rows: int = EXPORT_BATCH_ROWS) -> None:
        self.reader = RecorderReader(path, batch_rows=batch_rows)
        self.since = since
        self.until = until
        self.names: list[str] = []
        self.rows = 0

    def __enter__(self) -> Export:
        try:
            self.reader.open()
            names = self.reader.names()
        except RecorderError as exc:
            self.reader.close()
            raise ExportError(f"{self.reader.path}: {exc.reason}") from None
        self.names = ["time", *_FIRST, *(n for n in names if n not in _FIRST and n not in _DROP)]
        return self

    def __exit__(self, *exc: object) -> None:
        self.reader.close()

    def batches(self) -> Iterator[Table]:
        try:
            for cols in self.reader.batches(self.since, self.until):
                out = {"time": np.array([_iso(w) for w in cols["wall_s"].tolist()],
                                        dtype=object)}
                out.update((name, cols[name]) for name in self.names[1:])
                self.rows += len(out["time"])
                yield Table(out)
        except RecorderError as exc:
            raise ExportError(f"{self.reader.path}: {exc.reason}") from None


def _cells(col: npt.NDArray[Any]) -> list[str]:
    """One column as CSV cells: floats as repr (shortest round trip), empty when
    missing or not finite; booleans 1/0."""
    if col.dtype.kind == "b":
        return ["1" if v else "0" for v in col.tolist()]
    if col.dtype.kind == "f":
        return [repr(v) if math.isfinite(v) else "" for v in col.tolist()]
    return [str(v) for v in col.tolist()]


def write_csv(export: Export, out: IO[str]) -> None:
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(export.names)
    for table in export.batches():
        writer.writerows(zip(*(_cells(c) for c in table.columns.values()), strict=True))


def write_csv_file(export: Export, path: Path) -> None:
    with path.open("w", encoding="utf-8", newline="") as f:
        write_csv(export, f)


def _arrow_type(name: str) -> Any:
    import pyarrow as pa

    if name in ("time", "state"):
        return pa.string()
    if name in ("seq", "cycle"):
        return pa.int64()
    if name == "valid" or name.startswith("valid."):
        return pa.bool_()
    return pa.float64()


def write_parquet(export: Export, path: Path) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    schema = pa.schema([(name, _arrow_type(name)) for name in export.names])
    with pq.ParquetWriter(path, schema) as writer:
        for table in export.batches():
            arrays = []
            for field in schema:
                col = table.columns[field.name]
                if col.dtype.kind == "f":
                    arrays.append(pa.array(col, mask=~np.isfinite(col), type=field.type))
                else:
                    arrays.append(pa.array(col.tolist(), type=field.type))
            writer.write_table(pa.Table.from_arrays(arrays, schema=schema))
