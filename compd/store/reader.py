"""The one reader of a recorder database: `compd export`, `fit`, `replay` and the
status page read the daemon's recorder through `RecorderReader`.

Opening checks the file before SQLite sees it and ends each refusal in one
exception (`compd.store.opening`: not a readable regular file, `InputError`, exit
66; not an SQLite file, not the recorder's tables, each an ordinary table and never
a view; a corrupt ``meta``: `RecorderError`, exit 65 in the commands). There is no
size cap: the rows are streamed. A file is data, never code: each statement
is aborted after `query_s` seconds (SQLite's progress handler), and a field
longer than `compd.infiles.MAX_FIELD_CHARS` (as a CSV cell) is refused naming
its row and column before it reaches Python, so a 100 MB cell costs SQLite's
one read of it, not its parsing.

`batches(since, until)` yields the rows whose wall-clock stamp lies in
[since, until), oldest first (by the table's rowid, which is the recorder's
``seq``), as numpy columns of at most `batch_rows` rows each: memory is one
batch, whatever the file's size. The window is found on the ``wall_s`` index
(the first and last rowid inside it), the rows up to the newest committed when
the iteration starts; each batch is its own short read (WAL: the daemon goes on
writing and checkpointing meanwhile), and a row retention deletes between two
batches is simply not read. A row the daemon cannot have written (JSON that is
not an object or nests without end, a text where a number belongs) raises
`RecorderError` naming its ``seq``.

`read(since, until)` is the same rows as whole columns, counted first and
filled a batch at a time: memory is the numbers' 8 bytes each and one batch. The
columns of a batch are `compd.store.columns`'s.

`history(since, max_points)` is the status page's plot: at most `max_points`
rows of (wall_s, offset_um, model_um) picked by stride on ``seq``.

The per-axis rows (table ``axes``) are read by `compd.store.axis_reads.AxisReads`'s
methods: all at once (`axes`), or a batch of samples' at a time (`axis_batch`).
"""

from __future__ import annotations

import contextlib
import math
import sqlite3
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from compd.infiles import MAX_FIELD_CHARS
from compd.store.axis_reads import AxisReads
from compd.store.columns import CORRUPT, Columns, bounded_fields, build_columns, floats
from compd.store.opening import check_tables, connect_readonly
from compd.store.schema import (
    CHANNELS_KEY,
    FIXED_COLUMNS,
    SAMPLE_COLUMNS,
    TERMS_KEY,
    RecorderError,
    meta_names,
    scan_terms,
)

__all__ = ["BATCH_ROWS", "Columns", "RecorderReader", "read_samples"]

#: the batch builder, called by this name (tests wrap it to watch the batches)
_build = build_columns


#: rows per batch: a few hundred kB of numbers, one short read of SQLite
BATCH_ROWS = 4096
#: how long a read waits for a database another process holds locked
LOCK_WAIT_S = 5.0
#: how long one statement may run: a batch, a count of a year's rows or the probes take
#: seconds at most; one still running after this is stopped (RecorderError), whatever
#: the file makes SQLite do
QUERY_S = 60.0
#: SQLite virtual-machine steps between two looks at the clock
_PROGRESS_STEPS = 10_000

_PICK = """
WITH RECURSIVE pick(s) AS (SELECT ? UNION ALL SELECT s - ? FROM pick WHERE s - ? >= ?)
SELECT wall_s, offset_um, model_um FROM pick JOIN samples ON samples.seq = pick.s
ORDER BY pick.s"""
#: what `RecorderReader.probes` reads of a probe
_PROBE_FIELDS = ("probes.seq", "samples.mono_s", "probes.measured_um", "probes.model_um",
                 "probes.accepted", "probes.reason")


class _Window:
    """[since, until) on ``wall_s`` as SQL: `sql` (" AND ..." terms) and its `bounds`."""

    def __init__(self, since: float | None, until: float | None) -> None:
        self.sql = ""
        self.bounds: list[float] = []
        if since is not None:
            self.sql += " AND wall_s >= ?"
            self.bounds.append(since)
        if until is not None:
            self.sql += " AND wall_s < ?"
            self.bounds.append(until)


class RecorderReader(AxisReads):
    """A recorder database opened read-only (see the module docstring).

    Use as a context manager, or `open()` and `close()`. `channels` and `terms`
    name every channel and model term the file holds, in the order first seen.
    Each statement may run `query_s` seconds (default `QUERY_S`) on `clock`
    (default: the monotonic clock).
    """

    def __init__(self, path: str | Path, *, batch_rows: int = BATCH_ROWS,
                 timeout_s: float = LOCK_WAIT_S, query_s: float | None = None,
                 clock: Callable[[], float] | None = None) -> None:
        if batch_rows < 1:
            raise ValueError(f"batch_rows must be >= 1, got {batch_rows}")
        self.path = Path(path)
        self.batch_rows = batch_rows
        self.timeout_s = timeout_s
        self.query_s = QUERY_S if query_s is None else query_s
        self.channels: tuple[str, ...] = ()
        self._terms: tuple[str, ...] | None = None
        self._conn: sqlite3.Connection | None = None
        self._clock = time.monotonic if clock is None else clock
        self._deadline = math.inf
        self._late = False

    def __enter__(self) -> RecorderReader:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def open(self) -> None:
        """Check the file and open it. Raises InputError or RecorderError."""
        conn = connect_readonly(self.path, self.timeout_s)
        conn.set_progress_handler(self._too_late, _PROGRESS_STEPS)
        try:
            with self._timed("not a recorder database"):
                check_tables(conn, self.path)
                columns = {str(r[1]) for r in conn.execute("PRAGMA table_info(samples)")}
            missing = [c for c in SAMPLE_COLUMNS if c not in columns]
            if missing:
                raise RecorderError(self.path, f"not a recorder database (samples lacks {missing})")
            self.channels = tuple(self._meta_names(conn, CHANNELS_KEY) or ())
            clash = sorted(set(self.channels).intersection(FIXED_COLUMNS))
            if clash:
                raise RecorderError(self.path,
                                    f"channel name(s) {clash} collide with fixed columns")
            terms = self._meta_names(conn, TERMS_KEY)
            self._terms = None if terms is None else tuple(terms)
        except RecorderError:
            conn.close()
            raise
        self._conn = conn

    def _too_late(self) -> int:
        """SQLite's progress handler: nonzero (abort the statement) past the deadline."""
        if self._clock() > self._deadline:
            self._late = True
            return 1
        return 0

    @contextlib.contextmanager
    def _timed(self, what: str) -> Iterator[None]:
        """The statements inside run against a deadline `query_s` away; an SQLite error
        (the deadline's among them) ends in one RecorderError, `what` first."""
        self._deadline, self._late = self._clock() + self.query_s, False
        try:
            yield
        except sqlite3.Error as exc:
            if self._late:
                raise RecorderError(self.path, f"{what}: a read stopped after {self.query_s:g} "
                                    "s (one read of a recorder compd wrote takes seconds)"
                                    ) from None
            raise RecorderError(self.path, f"{what}: {exc}") from None
        finally:
            self._deadline = math.inf

    def close(self) -> None:
        conn, self._conn = self._conn, None
        if conn is not None:
            conn.close()

    @property
    def terms(self) -> tuple[str, ...]:
        """The model terms; found in the rows when the file does not list them."""
        if self._terms is None:
            conn = self._connection()
            with self._timed("corrupt contributions"):
                self._terms = tuple(scan_terms(conn, MAX_FIELD_CHARS))
        return self._terms

    def batches(self, since: float | None = None, until: float | None = None, *,
                detail: bool = True) -> Iterator[Columns]:
        """The rows stamped in [since, until), a batch of columns at a time."""
        terms = self.terms if detail else ()  # the column list, before the first batch
        window = _Window(since, until)
        span = self._span(window)
        if span is not None:
            yield from self._batches(window, span, terms, detail)

    def names(self, *, detail: bool = True) -> list[str]:
        """The columns a batch has, in their order."""
        return list(self._columns([], self.terms if detail else (), detail))

    def read(self, since: float | None = None, until: float | None = None, *,
             detail: bool = True) -> Columns:
        """Every row in the window as whole columns, counted first and filled a batch
        at a time (memory: the columns, 8 bytes per number, and one batch)."""
        terms = self.terms if detail else ()
        empty = self._columns([], terms, detail)
        window = _Window(since, until)
        span = self._span(window)
        if span is None:
            return empty
        n = self._count(window, span)
        whole = {k: np.empty(n, dtype=v.dtype) for k, v in empty.items() if v.dtype.kind != "U"}
        parts = {k: [v] for k, v in empty.items() if k not in whole}  # text: width unknown
        filled = 0
        for batch in self._batches(window, span, terms, detail):
            m = len(batch["mono_s"])
            if filled + m > n:  # rows inside the span committed since the count
                n = filled + m
                whole = {name: np.resize(col, n) for name, col in whole.items()}
            for name, col in whole.items():
                col[filled:filled + m] = batch[name]
            for name, texts in parts.items():
                texts.append(batch[name])
            filled += m
        return {k: whole[k][:filled] if k in whole else np.concatenate(parts[k]) for k in empty}

    def _span(self, window: _Window) -> tuple[int, int] | None:
        """The first and last rowid stamped inside the window (its index), or None."""
        sql = "SELECT MIN(rowid), MAX(rowid) FROM samples"
        conn = self._connection()
        with self._timed("cannot read"):
            first, last = conn.execute(
                sql + (f" WHERE {window.sql[5:]}" if window.sql else ""), window.bounds
            ).fetchone()
        return None if first is None else (int(first), int(last))

    def _seq_span(self, since: float | None, until: float | None) -> tuple[int, int] | None:
        return self._span(_Window(since, until))

    def _count(self, window: _Window, span: tuple[int, int]) -> int:
        conn = self._connection()
        with self._timed("cannot read"):
            return int(conn.execute(
                f"SELECT COUNT(*) FROM samples WHERE rowid BETWEEN ? AND ?{window.sql}",
                (*span, *window.bounds)).fetchone()[0])

    def _batches(self, window: _Window, span: tuple[int, int], terms: tuple[str, ...],
                 detail: bool) -> Iterator[Columns]:
        columns = ["seq", "cycle", "mono_s", "wall_s", "offset_um", "model_um", "valid",
                   "state", "channels", *(["validity", "contributions"] if detail else [])]
        select = (f"SELECT rowid, {bounded_fields([f'samples.{c}' for c in columns])} FROM samples"
                  f" WHERE rowid > ? AND rowid <= ?{window.sql.replace('wall_s', '+wall_s')}"
                  " ORDER BY rowid LIMIT ?")
        conn = self._connection()
        after, last = span[0] - 1, span[1]
        while True:
            with self._timed("cannot read"):
                rows = conn.execute(select, (after, last, *window.bounds, self.batch_rows)
                                    ).fetchall()
            if not rows:
                return
            self._refuse_long(rows, "seq")
            after = int(rows[-1][0])
            yield self._columns([r[:-1] for r in rows], terms, detail)

    def _refuse_long(self, rows: list[Any], which: str) -> None:
        """Refuse the first row with a field past MAX_FIELD_CHARS, naming it by its first
        value (the recorder's ``seq``) and the column (a row's last value, `_fields`)."""
        for row in rows:
            if row[-1] is not None:
                raise RecorderError(self.path, f"{which} {row[0]!r}, column {row[-1]}: a field "
                                    f"longer than {MAX_FIELD_CHARS // 1024} KiB (no value "
                                    "compd records is that long); not a recorder compd wrote")

    def history(self, since_wall_s: float,
                max_points: int) -> list[tuple[float, float | None, float | None]]:
        """(wall_s, offset_um, model_um) of at most `max_points` rows from the first
        stamped at or after `since_wall_s` to the newest, evenly spaced by ``seq``, the
        newest always included, oldest first: a bounded number of key look-ups."""
        conn = self._connection()
        try:
            with self._timed("cannot read"):
                last = conn.execute("SELECT MAX(seq) FROM samples").fetchone()[0]
                first = conn.execute("SELECT seq FROM samples WHERE wall_s >= ? ORDER BY "
                                     "wall_s LIMIT 1", (since_wall_s,)).fetchone()
                if last is None or first is None:
                    return []
                lo = min(int(first[0]), int(last))
                stride = max(1, math.ceil((int(last) - lo + 1) / max(1, max_points)))
                rows = conn.execute(_PICK, (int(last), stride, stride, lo)
                                    ).fetchmany(max_points)
            return [(float(w), o, m) for w, o, m in rows]
        except CORRUPT as exc:
            raise RecorderError(self.path, f"corrupt rows ({type(exc).__name__})") from None

    def probes(self) -> Columns:
        """Every probe (the ``probes`` table), oldest first, with its sample's clock:
        ``seq`` (int64), ``mono_s``, ``measured_um``, ``model_um`` (float64, NaN where none
        was recorded), ``reason`` (str: "" for an accepted probe, else why it was
        refused). A file from before probes were recorded has none: empty columns."""
        conn = self._connection()
        try:
            rows = self._joined(conn, "probes", _PROBE_FIELDS, "probes.seq", "probe")
            return {
                "seq": np.array([r[0] for r in rows], dtype=np.int64),
                "mono_s": floats(r[1] for r in rows),
                "measured_um": floats(r[2] for r in rows),
                "model_um": floats(r[3] for r in rows),
                "reason": np.array(["" if r[4] else str(r[5] or "refused") for r in rows],
                                   dtype=str),
            }
        except CORRUPT as exc:
            raise RecorderError(self.path, f"corrupt probe rows ({type(exc).__name__}); "
                                "not a recorder compd wrote") from None

    def _joined(self, conn: sqlite3.Connection, table: str, fields: Sequence[str],
                order_by: str, what: str) -> list[Any]:
        """`fields` of every row of `table` joined to its sample, ordered by `order_by`,
        each field within MAX_FIELD_CHARS (`_refuse_long`, naming the row by its
        ``seq``: an axis row's rowid is not its sample's); none when the file has no
        such table (written before it was recorded)."""
        with self._timed(f"cannot read its {table}"):
            if conn.execute("SELECT 1 FROM sqlite_schema WHERE name = ?",
                            (table,)).fetchone() is None:
                return []
            rows: list[Any] = conn.execute(
                f"SELECT {table}.seq, {bounded_fields(fields)} FROM {table}"
                f" JOIN samples ON samples.seq = {table}.seq ORDER BY {order_by}").fetchall()
        self._refuse_long(rows, f"{what} seq")
        return [r[1:-1] for r in rows]

    def _connection(self) -> sqlite3.Connection:
        if self._conn is None:
            raise RecorderError(self.path, "not open")
        return self._conn

    def _meta_names(self, conn: sqlite3.Connection, key: str) -> list[str] | None:
        try:
            with self._timed("not a recorder database"):
                return meta_names(conn, key, MAX_FIELD_CHARS)
        except ValueError as exc:
            raise RecorderError(self.path, f"corrupt: {exc}; not a recorder compd wrote"
                                ) from None

    def _columns(self, rows: list[Any], terms: tuple[str, ...], detail: bool) -> Columns:
        try:
            return _build(rows, self.channels, terms, detail)
        except CORRUPT as exc:
            error, bad = exc, rows[0]
        for row in rows:  # which one: the batch again, a row at a time
            try:
                _build([row], self.channels, terms, detail)
            except CORRUPT as exc:
                error, bad = exc, row
                break
        raise RecorderError(self.path, f"corrupt row, seq {bad[1]!r} ({type(error).__name__}: "
                            f"{str(error)[:80]}); not a recorder compd wrote")


def read_samples(path: str | Path, since: float | None = None,
                 until: float | None = None) -> Columns:
    """Every sample of a recorder database (in [since, until) when given) as whole
    columns (see the module docstring). Raises InputError or RecorderError."""
    with RecorderReader(path) as reader:
        return reader.read(since, until)
