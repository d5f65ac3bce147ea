"""The daemon's recorder as a table for a historian or a spreadsheet, streamed.

`Export(path, since, until)` opens a recorder database (`compd.store.reader`)
and yields the rows whose wall-clock stamp lies in [since, until) a batch at a
time, so that a month's recorder is written in the memory of one batch.
Columns, in this order: ``time`` (ISO 8601 UTC of the wall clock), ``wall_s``
(Unix seconds), ``mono_s`` (machine seconds since the daemon started), ``seq``,
``cycle``, ``state``, ``valid``, ``offset_um`` (written and confirmed),
``model_um``, one column per channel, ``valid.<channel>`` and
``contribution.<term>``, then for each axis the recorder holds in the window
(``[output.axes]``: x, y, z, then tool) one column per column of its row in the
recorder's ``axes`` table, named ``<axis>.<column>``
(`compd.store.axis_columns.EXPORT_AXIS_COLUMNS`): ``x.state``, ``x.cause``,
``x.in_force``, ``x.value_um``, ``x.value_sent_um``, ``x.value_confirmed_um``,
``x.value_model_um``, ``x.slope_um_m``, ``x.slope_sent_um_m``,
``x.slope_confirmed_um_m``, ``x.slope_model_um_m``, ``x.reference_mm``,
``x.position_mm``, ``x.offset_um``. Each batch's axis rows are read with it (a key
range of the ``axes`` index) and joined on ``seq``. Missing numbers, and every
cell of an axis in a sample without that axis's row, are empty CSV cells and
Parquet nulls. A recorder without axes exports without those columns.

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

from compd.store.axis_columns import AXIS_FLAG_COLUMNS, AXIS_TEXT_COLUMNS, EXPORT_AXIS_COLUMNS
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
        self.axes: tuple[str, ...] = ()
        self._sample_names: list[str] = []
        self.rows = 0

    def __enter__(self) -> Export:
        try:
            self.reader.open()
            names = self.reader.names()
            self.axes = self.reader.axis_names(self.since, self.until)
        except RecorderError as exc:
            self.reader.close()
            raise ExportError(f"{self.reader.path}: {exc.reason}") from None
        self.names = ["time", *_FIRST, *(n for n in names if n not in _FIRST and n not in _DROP)]
        axis_names = [f"{a}.{c}" for a in self.axes for c in EXPORT_AXIS_COLUMNS]
        clash = sorted(set(axis_names).intersection(self.names))
        if clash:
            self.reader.close()
            raise ExportError(f"{self.reader.path}: channel or term column(s) {clash} "
                              "take the names of axis columns; not a recorder compd wrote")
        self._sample_names = self.names[1:]
        self.names += axis_names
        return self

    def __exit__(self, *exc: object) -> None:
        self.reader.close()

    def batches(self) -> Iterator[Table]:
        try:
            for cols in self.reader.batches(self.since, self.until):
                out = {"time": np.array([_iso(w) for w in cols["wall_s"].tolist()],
                                        dtype=object)}
                out.update((name, cols[name]) for name in self._sample_names)
                if self.axes:
                    out.update(self._axis_cells(cols["seq"]))
                self.rows += len(out["time"])
                yield Table(out)
        except RecorderError as exc:
            raise ExportError(f"{self.reader.path}: {exc.reason}") from None

    def _axis_cells(self, seq: npt.NDArray[np.int64]) -> dict[str, npt.NDArray[Any]]:
        """Every axis's columns of the samples `seq` (a batch: ascending, not empty),
        joined on ``seq``: a sample without a row for an axis has NaN (a number) or
        None (a text or flag) in that axis's columns."""
        rows = self.reader.axis_batch(int(seq[0]), int(seq[-1]), self.axes)
        last = seq.size - 1
        out: dict[str, npt.NDArray[Any]] = {}
        for axis in self.axes:
            mine = np.flatnonzero(rows["axis"] == axis)
            at = np.minimum(np.searchsorted(seq, rows["seq"][mine]), last)
            # a row of a sample inside the batch's seq range but stamped outside the window
            inside = seq[at] == rows["seq"][mine]
            at, mine = at[inside], mine[inside]
            for name in EXPORT_AXIS_COLUMNS:
                col = np.full(seq.size, np.nan) if _is_number(name) \
                    else np.full(seq.size, None, dtype=object)
                col[at] = rows[name][mine]
                out[f"{axis}.{name}"] = col
        return out


def _is_number(axis_column: str) -> bool:
    return axis_column not in AXIS_TEXT_COLUMNS and axis_column not in AXIS_FLAG_COLUMNS


def _cells(col: npt.NDArray[Any]) -> list[str]:
    """One column as CSV cells: floats as repr (shortest round trip), empty when
    missing or not finite; booleans 1/0."""
    if col.dtype.kind == "b":
        return ["1" if v else "0" for v in col.tolist()]
    if col.dtype.kind == "f":
        return [repr(v) if math.isfinite(v) else "" for v in col.tolist()]
    if col.dtype.kind == "O":  # an axis's text or flag: None where it has no row
        return ["" if v is None else "1" if v is True else "0" if v is False else str(v)
                for v in col.tolist()]
    return [str(v) for v in col.tolist()]


def write_csv(export: Export, out: IO[str]) -> None:
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(export.names)
    for table in export.batches():
        writer.writerows(zip(*(_cells(c) for c in table.columns.values()), strict=True))


def write_csv_file(export: Export, path: Path) -> None:
    with path.open("w", encoding="utf-8", newline="") as f:
        write_csv(export, f)


def _arrow_type(name: str, axes: tuple[str, ...]) -> Any:
    import pyarrow as pa

    axis, _, column = name.partition(".")
    if axis in axes and column in EXPORT_AXIS_COLUMNS:  # a channel is never named so (Export)
        return (pa.string() if column in AXIS_TEXT_COLUMNS else
                pa.bool_() if column in AXIS_FLAG_COLUMNS else pa.float64())
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

    schema = pa.schema([(name, _arrow_type(name, export.axes)) for name in export.names])
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
