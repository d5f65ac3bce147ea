"""Streaming parse of a CSV calibration record into float64 columns.

Rows are read one at a time from the text stream and stored straight into a
preallocated (columns × rows) float64 array, sized from the file's length and
the first row's and grown by half when the guess was short: a 200 MB record
never becomes a list of strings. Each refusal names the file line and column
(`compd.offline.records` explains the rules); the numbers are checked as they come.
"""

from __future__ import annotations

import csv
import math
import operator
from collections.abc import Callable, Iterator, Sequence
from typing import TextIO

import numpy as np
import numpy.typing as npt

from compd.offline.record_cells import RecordError, parse_float, parse_iso

FloatArray = npt.NDArray[np.float64]

TimeColumn = Callable[[list[str], str], tuple[int, bool]]
#: (columns not parsed: text the caller drops, stored as 0.0; columns whose empty
#: cell is a missing number, stored as NaN) by header
TextColumns = Callable[[list[str]], tuple[frozenset[int], frozenset[int]]]
#: the columns stored, by (header, index of the time column): every cell is still
#: parsed and checked, only these are kept (None: every column)
Stored = Callable[[list[str], int], list[int]]


def _no_text(header: list[str]) -> tuple[frozenset[int], frozenset[int]]:
    return frozenset(), frozenset()


class _Grower:
    """A (columns × capacity) float64 buffer filled row by row."""

    def __init__(self, ncols: int, capacity: int) -> None:
        self.data: FloatArray = np.empty((ncols, max(16, capacity)), dtype=np.float64)
        self.n = 0

    def append(self, values: Sequence[float]) -> None:
        if self.n == self.data.shape[1]:
            bigger = np.empty((self.data.shape[0], self.n + self.n // 2 + 16), np.float64)
            bigger[:, :self.n] = self.data
            self.data = bigger
        self.data[:, self.n] = values
        self.n += 1

    def result(self) -> FloatArray:
        """The rows filled, the capacity beyond them given back: each column
        moved down to follow the one before it within the buffer, then the
        buffer shrunk in place (a month at 1 s read with a guess 14 % long held
        20 MB of unused capacity for the whole fit; no second copy at the peak)."""
        ncols, cap = self.data.shape
        n = self.n
        if n == cap:
            return self.data
        flat = self.data.reshape(-1)
        for i in range(1, ncols):
            flat[i * n:(i + 1) * n] = flat[i * cap:i * cap + n]
        del flat
        self.data.resize((ncols, n), refcheck=False)  # nothing else refers to the buffer
        return self.data


def _slow_row(row: list[str], header: list[str], t_idx: int, is_iso: bool, where: str,
              line_no: int, skip: frozenset[int] = frozenset(),
              blank: frozenset[int] = frozenset()) -> list[float] | None:
    """The row parsed cell by cell (naming the bad one), or None when blank."""
    if all(not c.strip() for c in row):
        return None
    if len(row) != len(header):
        raise RecordError(f"{where}: row {line_no}: {len(row)} fields, the header has "
                          f"{len(header)}")
    out: list[float] = []
    for i, cell in enumerate(row):
        if i in skip:
            out.append(0.0)
        elif i in blank and not cell.strip():
            out.append(math.nan)
        elif i == t_idx and is_iso:
            out.append(parse_iso(cell, f"{where}: row {line_no}, column {header[i]!r}"))
        else:
            out.append(parse_float(cell, where, line_no, header[i]))
    return out


def parse_csv(text: TextIO, where: str, size: int, time_column: TimeColumn,
              text_columns: TextColumns = _no_text, stored: Stored | None = None
              ) -> tuple[list[str], int, FloatArray]:
    """(header, index of the time column, data[column, row]) of a CSV stream
    of `size` bytes; times as read (ISO 8601 as POSIX seconds). With `stored`,
    only those columns are kept (the header and the time column's index are
    then of the columns kept), each cell of the others still checked. What the
    csv module cannot split (a field over its limit of 128 KiB) is a RecordError
    naming the line."""
    reader = csv.reader(text)
    try:
        return _parse(reader, where, size, time_column, text_columns, stored)
    except csv.Error as exc:
        reason = str(exc)
        if "field larger than field limit" in reason:
            reason = (f"a field is longer than {csv.field_size_limit() // 1024} KiB "
                      "(no number is that long); not a calibration record")
        raise RecordError(f"{where}: line {reader.line_num}: {reason}") from None


def _parse(reader: Iterator[list[str]], where: str, size: int, time_column: TimeColumn,
           text_columns: TextColumns, stored: Stored | None
           ) -> tuple[list[str], int, FloatArray]:
    header = next(reader, None)
    if not header or not any(h.strip() for h in header):
        raise RecordError(f"{where}: empty file (a header line is required)")
    header = [h.strip() for h in header]
    dup = sorted({h for h in header if header.count(h) > 1})
    if dup:
        raise RecordError(f"{where}: duplicated column name(s) {dup} in the header")
    t_idx, is_iso = time_column(header, where)
    skip, blank = text_columns(header)
    numbers = [i for i in range(len(header)) if i not in skip and i not in blank]
    ncols = len(header)
    kept = sorted(set(stored(header, t_idx)) | {t_idx}) if stored is not None else None
    if kept is not None and len(kept) == ncols:
        kept = None
    pick = _picker(kept)
    buf: _Grower | None = None
    head: list[Sequence[float]] = []  # the first rows, to size the buffer from their length
    head_bytes = 0
    for line_no, row in enumerate(reader, start=2):
        values: list[float] | None
        try:
            if len(row) != ncols or is_iso:
                raise ValueError
            if skip or blank:
                values = [0.0] * ncols
                for i in numbers:
                    values[i] = float(row[i])
                if not math.isfinite(sum(values[i] for i in numbers)):
                    raise ValueError
                for i in blank:
                    values[i] = float(row[i]) if row[i].strip() else math.nan
                    if row[i].strip() and not math.isfinite(values[i]):
                        raise ValueError
            else:
                values = [float(c) for c in row]
                if not math.isfinite(sum(values)):
                    raise ValueError
        except (ValueError, OverflowError):
            values = _slow_row(row, header, t_idx, is_iso, where, line_no, skip, blank)
            if values is None:
                continue
        if buf is None:
            head.append(pick(values))
            head_bytes += sum(len(c) for c in row) + ncols
            if len(head) < HEAD_ROWS:
                continue
            buf = _start(len(head[0]), size, head, head_bytes)
        else:
            buf.append(pick(values))
    if buf is None:
        buf = _start(ncols if kept is None else len(kept), size, head, head_bytes)
    if kept is None:
        return header, t_idx, buf.result()
    return [header[i] for i in kept], kept.index(t_idx), buf.result()


def _picker(kept: list[int] | None) -> Callable[[list[float]], Sequence[float]]:
    """The values of the columns `kept` out of a row's (None: all of them)."""
    if kept is None:
        return lambda values: values
    if len(kept) == 1:
        only = kept[0]
        return lambda values: (values[only],)
    get = operator.itemgetter(*kept)  # one C call per row
    return get


#: rows read before the buffer is sized from their mean length
HEAD_ROWS = 256


def _start(ncols: int, size: int, head: list[Sequence[float]], head_bytes: int) -> _Grower:
    mean = head_bytes / max(1, len(head))
    buf = _Grower(ncols, int(1.05 * size / max(mean, 1.0)) + 16)
    for values in head:
        buf.append(values)
    return buf
