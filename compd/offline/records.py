"""Calibration records: what `compd fit` and `compd replay` read.

A record is a CSV file with a header: a time column (``time_s`` in seconds,
or ISO 8601 timestamps in a column named ``time``/``timestamp``/``datetime``
or simply the first column), one column per channel (named as in the daemon
config, temperatures in °C) and the measured displacement (µm), whose name
the command line gives.

The record is checked, never repaired: a gap, a duplicated or backwards
timestamp, jittery sampling, an empty or non-numeric cell, or a column whose
magnitude betrays a unit mistake (a temperature in mK, a displacement in mm)
raises `RecordError` naming the row (1-based line of the file) and column.
A model fitted on silently resampled data would be silently wrong.

The daemon's own SQLite sample recorder (`compd.runtime.recorder`, a ``.db``,
``.sqlite`` or ``.sqlite3`` file) is read by `read_recorder_record`: one
column per recorded channel, plus ``offset_um`` / ``model_um`` when every
sample has them, on the daemon's sample clock. A missing channel value is
refused like an empty CSV cell, a daemon restart (the clock starts again)
like a backwards timestamp; rows are numbered as in a CSV export (line 2 is
the first sample). `read_record` picks the reader by the file's suffix. A CSV
that `compd export` wrote (known by its columns, `is_export`) reads as its
database: ``mono_s`` by ``cycle`` is the time (machine seconds; ``time`` and
``wall_s`` are the wall clock), ``time``, ``wall_s``, ``seq``, ``state``,
``valid``, ``valid.<channel>``, ``contribution.<term>`` and each axis's
``<axis>.<column>`` (``x.state``, ``x.value_um``…: the recorder's ``axes`` rows,
which its database does not read as channels either) are not channels, and
``offset_um``/``model_um`` are kept when no cell of theirs is empty. An axis's
columns are neither parsed nor held (a text, a flag, or a number empty where the
sample has no row for the axis).

The sampling checks are `compd.offline.sampling`; their names are importable from here.
"""

from __future__ import annotations

import hashlib
import io
import os
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from compd.infiles import MAX_RECORD_BYTES, open_input
from compd.offline.channel_kind import ChannelKind, channel_kind
from compd.offline.record_cells import RecordError as RecordError  # noqa: PLC0414  (callers' import)
from compd.offline.sampling import GAP_FACTOR, JITTER_TOLERANCE, check_sampling, recorder_time
from compd.store.axis_columns import is_axis_column

FloatArray = npt.NDArray[np.float64]

__all__ = ["GAP_FACTOR", "JITTER_TOLERANCE", "RecordError", "check_sampling", "recorder_time"]


#: header names accepted for an ISO 8601 time column
_ISO_TIME_NAMES = ("time", "timestamp", "datetime", "date_time", "time_iso")
#: a temperature (°C) whose median magnitude exceeds this is probably in mK
MAX_PLAUSIBLE_TEMP_C = 1000.0
#: a displacement record whose whole range is below this (µm) is probably in mm
MIN_PLAUSIBLE_RANGE_UM = 0.5


@dataclass(frozen=True)
class Record:
    """A checked record: uniform sampling, finite values, one array per column."""

    path: str
    sha256: str
    time_s: FloatArray
    period_s: float
    columns: dict[str, FloatArray]

    def __len__(self) -> int:
        return int(self.time_s.size)

    def column(self, name: str) -> FloatArray:
        self._former_spelling(name)
        try:
            return self.columns[name]
        except KeyError:
            raise RecordError(f"{self.path}: no column {name!r}; the record has "
                              f"{sorted(self.columns)}") from None

    def require(self, names: Iterable[str]) -> None:
        names = list(names)
        for name in names:
            self._former_spelling(name)
        missing = sorted(set(names) - set(self.columns))
        if missing:
            raise RecordError(f"{self.path}: missing column(s) {missing}; the record has "
                              f"{sorted(self.columns)}")

    def _former_spelling(self, name: str) -> None:
        """A column wanted under one spelling of a renamed simulator channel and held
        under the other (`drivers.sim.renamed`: ``speed_rpm`` is now ``spindle_rpm``)
        is filed under the name wanted, with the warning once per process: an old
        record read with today's names, or an old model or command line on a new
        record. The samples then carry the name the model steps on."""
        from drivers.sim.renamed import FORMER_NAMES, counterpart, warn_former

        other = counterpart(name)
        if name in self.columns or other is None or other not in self.columns:
            return
        self.columns[name] = self.columns.pop(other)
        warn_former(other if other in FORMER_NAMES else name,
                    f"{self.path}" if other in FORMER_NAMES else "the model or command line")

    def samples(self) -> Samples:
        """One dict per row (channel -> float), as the daemon sees a sample;
        made as they are read, never all at once."""
        return Samples(self.columns, len(self))


class Samples(Sequence[dict[str, float]]):
    """The rows of a record as dicts, built a block at a time on iteration."""

    BLOCK = 8192

    def __init__(self, columns: dict[str, FloatArray], n: int) -> None:
        self._columns = columns
        self._n = n

    def __len__(self) -> int:
        return self._n

    # rows by index only: a slice would build the dicts it exists to avoid building (Sequence
    # declares the slice overload too, so mypy calls the narrower signature an override)
    def __getitem__(self, i: int) -> dict[str, float]:  # type: ignore[override]
        if not -self._n <= i < self._n:
            raise IndexError(i)
        return {k: float(v[i]) for k, v in self._columns.items()}

    def __iter__(self) -> Iterator[dict[str, float]]:
        names = list(self._columns)
        for lo in range(0, self._n, self.BLOCK):
            block = [self._columns[n][lo:lo + self.BLOCK].tolist() for n in names]
            for row in zip(*block, strict=True):
                yield dict(zip(names, row, strict=True))


def file_sha256(path: str | Path) -> str:
    h = hashlib.sha256()
    with Path(path).open("rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


#: the columns by which a CSV is known as `compd export`'s (compd.offline.export)
EXPORT_MARKS = frozenset({"time", "wall_s", "mono_s", "seq", "cycle", "state", "valid"})
#: an export's columns that are not channels: text, flags, the bookkeeping and the
#: terms' parts (``valid.<channel>``, ``contribution.<term>``)
_EXPORT_SKIP = frozenset({"time", "wall_s", "seq", "state", "valid"})
_EXPORT_SKIP_PREFIXES = ("valid.", "contribution.")
#: an export's columns left empty where the daemon had no value; kept when full
_EXPORT_BLANK = frozenset({"offset_um", "model_um"})


def is_export(header: Sequence[str]) -> bool:
    """Whether a CSV header is `compd export`'s."""
    return {h.strip() for h in header} >= EXPORT_MARKS


def _export_text_columns(header: list[str]) -> tuple[frozenset[int], frozenset[int]]:
    """(skipped, may be empty) columns of a `compd export` CSV; none of another CSV."""
    if not is_export(header):
        return frozenset(), frozenset()
    skip = frozenset(i for i, h in enumerate(header)
                     if h in _EXPORT_SKIP or h.startswith(_EXPORT_SKIP_PREFIXES)
                     or is_axis_column(h))
    return skip, frozenset(i for i, h in enumerate(header) if h in _EXPORT_BLANK)


def _time_column(header: list[str], path: str) -> tuple[int, bool]:
    """(index, is_iso) of the time column: an export's machine seconds (``mono_s``,
    the daemon's sample clock, as read from its database), else ``time_s``, else
    an ISO 8601 column."""
    if is_export(header):
        return header.index("mono_s"), False
    lowered = [h.strip().lower() for h in header]
    if "time_s" in lowered:
        return lowered.index("time_s"), False
    for name in _ISO_TIME_NAMES:
        if name in lowered:
            return lowered.index(name), True
    raise RecordError(f"{path}: no time column: expected 'time_s' (seconds) or an ISO 8601 "
                      f"column named one of {list(_ISO_TIME_NAMES)}; header is {header}")


def read_csv_columns(path: str | Path, what: str, keep: Callable[[str], bool] | None = None
                     ) -> tuple[list[str], int, FloatArray]:
    """(header, index of the time column, data[column, row]) of a CSV file of numbers
    with a time column, streamed (`compd.offline.csvstream`); RecordError naming the
    file (and the row and column) on anything else. The one CSV reader of records and
    probe logs: the checks of what the rows mean are the caller's. `keep`: the
    only columns stored besides the time (every cell is still checked); an export's
    columns are all stored, its reading needs them, but for its axes' columns, which
    are neither parsed nor stored (four axes would be 56 columns of nothing held)."""
    from compd.offline.csvstream import parse_csv

    where = str(path)

    def stored(header: list[str], t: int) -> list[int]:
        if is_export(header):  # all but the axes' columns, which are no channels
            return [i for i, h in enumerate(header) if not is_axis_column(h)]
        return [i for i, h in enumerate(header) if i == t or keep is None or keep(h)]

    with open_input(path, what, MAX_RECORD_BYTES) as raw:
        size = os.fstat(raw.fileno()).st_size
        text = io.TextIOWrapper(raw, encoding="utf-8-sig", newline="")
        try:
            return parse_csv(text, where, size, _time_column, _export_text_columns, stored)
        except UnicodeDecodeError:
            raise RecordError(f"{where}: not a text (UTF-8) CSV file") from None
        except OSError as exc:
            raise RecordError(f"{where}: cannot read the {what} ({exc.strerror})") from None


def read_csv_record(path: str | Path, keep: Callable[[str], bool] | None = None) -> Record:
    """Read and check a CSV calibration record (see the module docstring),
    streamed row by row into float64 columns (`compd.offline.csvstream`): memory is
    the numbers' 8 bytes per cell, whatever the text's size. `keep`: the only
    columns held (`read_csv_columns`; the others are checked all the same)."""
    where = str(path)
    header, t_idx, data = read_csv_columns(path, "record", keep)
    if is_export(header):
        return _export_record(path, header, data)
    if data.shape[1] < 3:
        raise RecordError(f"{where}: {data.shape[1]} data row(s); a record needs at least 3")
    t = data[t_idx]
    period_s = check_sampling(t, where)
    t -= t[0]
    columns = {name: data[i] for i, name in enumerate(header) if i != t_idx}
    return Record(path=where, sha256=file_sha256(path), time_s=t, period_s=period_s,
                  columns=columns)


def _export_record(path: str | Path, header: list[str], data: FloatArray) -> Record:
    """A `compd export` CSV as the record its recorder database reads as: the same
    channels (``offset_um``/``model_um`` when every row has them), on the same
    clock (``mono_s`` by its ``cycle``, `recorder_time`); its text and bookkeeping
    columns (``time``, ``state``, ``valid``…) are not channels."""
    where = str(path)
    if data.shape[1] < 3:
        raise RecordError(f"{where}: {data.shape[1]} sample(s); a record needs at least 3")
    skip, blank = _export_text_columns(header)
    columns: dict[str, FloatArray] = {}
    for i, name in enumerate(header):
        if i in skip or name in ("mono_s", "cycle"):
            continue
        if i in blank and not np.all(np.isfinite(data[i])):
            continue
        columns[name] = data[i]
    time_s, period_s = recorder_time(data[header.index("mono_s")],
                                     data[header.index("cycle")].astype(np.int64), where)
    columns = {name: col[:time_s.size] for name, col in columns.items()}
    return Record(path=where, sha256=file_sha256(path), time_s=time_s, period_s=period_s,
                  columns=columns)


#: file suffixes read as the daemon's SQLite recorder
RECORDER_SUFFIXES = (".db", ".sqlite", ".sqlite3")


def read_record(path: str | Path, keep: Callable[[str], bool] | None = None) -> Record:
    """A calibration record from a CSV file or a recorder database (by suffix);
    `keep`: the only columns a CSV file's record holds (`read_csv_record`)."""
    if Path(path).suffix.lower() in RECORDER_SUFFIXES:
        return read_recorder_record(path)
    return read_csv_record(path, keep)


def columns_named(names: Iterable[str], speeds: bool = False) -> Callable[[str], bool]:
    """A `keep` for `read_record`: the columns `names` (under a renamed simulator
    channel's other spelling too, `Record.require` files it under the name
    asked for), with `speeds` every speed column besides."""
    from drivers.sim.renamed import counterpart

    wanted = set(names)
    return lambda c: (c in wanted or counterpart(c) in wanted
                      or (speeds and channel_kind(c) is ChannelKind.SPEED))


def read_recorder_record(path: str | Path) -> Record:
    """Read and check the daemon's SQLite sample recorder as a record, streamed
    (`compd.store.reader`): memory is the record's numbers, whatever the file's size."""
    from compd.store.reader import RecorderReader
    from compd.store.schema import FIXED_COLUMNS, RecorderError

    p = Path(path)
    where = str(p)
    try:
        with RecorderReader(p) as reader:
            cols = reader.read(detail=False)
    except RecorderError as exc:
        raise RecordError(f"{where}: {exc.reason}") from None
    t = np.asarray(cols["mono_s"], dtype=np.float64)
    if t.size < 3:
        raise RecordError(f"{where}: {t.size} sample(s); a record needs at least 3")
    if not np.all(np.isfinite(t)):
        raise RecordError(f"{where}: row {int(np.argmin(np.isfinite(t))) + 2}: no sample time")
    columns: dict[str, FloatArray] = {}
    for name in ("offset_um", "model_um"):
        col = np.asarray(cols[name], dtype=np.float64)
        if np.all(np.isfinite(col)):
            columns[name] = col
    for name, values in cols.items():
        if name in FIXED_COLUMNS:
            continue
        col = np.asarray(values, dtype=np.float64)
        bad = np.flatnonzero(~np.isfinite(col))
        if bad.size:
            raise RecordError(f"{where}: row {int(bad[0]) + 2}, column {name!r}: no valid value "
                              f"recorded ({bad.size} such sample(s); a missing sample is not "
                              "filled in; cut the record or repair it)")
        columns[name] = col
    time_s, period_s = recorder_time(t, np.asarray(cols["cycle"], dtype=np.int64), where)
    columns = {name: col[:time_s.size] for name, col in columns.items()}
    return Record(path=where, sha256=file_sha256(p), time_s=time_s, period_s=period_s,
                  columns=columns)


def check_units(record: Record, temperatures: Iterable[str], displacement: str) -> None:
    """Refuse columns whose magnitude betrays a unit mistake."""
    for name in temperatures:
        col = record.column(name)
        med = float(np.median(np.abs(col)))
        if med > MAX_PLAUSIBLE_TEMP_C:
            i = int(np.argmax(np.abs(col)))
            raise RecordError(
                f"{record.path}: column {name!r}: median magnitude {med:g} (row {i + 2}: "
                f"{col[i]:g}) is not a temperature in °C; it looks like mK (divide by 1000)")
    dz = record.column(displacement)
    span = float(dz.max() - dz.min())
    if 0.0 < span < MIN_PLAUSIBLE_RANGE_UM:
        raise RecordError(
            f"{record.path}: column {displacement!r}: the displacement spans only {span:.3g} "
            f"over the whole record ({dz.min():g} … {dz.max():g}); thermal growth and even "
            "probe noise are larger than that in µm: it looks like mm (multiply by 1000)")
    if span == 0.0:
        raise RecordError(f"{record.path}: column {displacement!r} is constant ({dz[0]:g}); "
                          "nothing to fit")


def speed_warnings(record: Record) -> list[str]:
    """Advice about the calibration design when the record has a speed column:
    a constant-speed heat-up alone generalises poorly (docs/calibration.md §1)."""
    names = [n for n in record.columns if channel_kind(n) is ChannelKind.SPEED]
    out: list[str] = []
    for name in names:
        s = record.columns[name]
        top = float(np.max(np.abs(s)))
        if top <= 0.0:
            continue
        running = np.abs(s) > 0.05 * top
        if not running.any():
            continue
        first_run = int(np.argmax(running))
        after = ~running[first_run:]
        stopped_s = float(after.sum()) * record.period_s
        cool_down = stopped_s >= 600.0
        levels = np.unique(np.round(s[running] / (0.02 * top)))
        steps = levels.size >= 3
        if not cool_down and not steps:
            out.append(f"{record.path}: column {name!r}: the spindle runs at one speed and never "
                       "cools down: a constant-speed heat-up alone generalises poorly; record a "
                       "cool-down after it or speed steps")
    return out


