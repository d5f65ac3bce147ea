"""The reads of the recorder's per-axis rows (table ``axes``): `RecorderReader` has
them from `AxisReads`, on its connection, deadline and field bound.

`axes()` is every row at once (a test, a look at a day); `axis_names(since,
until)` the axes with rows among a window's samples and `axis_batch(first, last,
axes)` the rows of one batch of samples (`compd export`: memory is the batch).
"""

from __future__ import annotations

from collections.abc import Sequence
from contextlib import AbstractContextManager
from typing import TYPE_CHECKING, Any

import numpy as np

from compd.store.axis_columns import axis_columns, axis_fields, known_axes
from compd.store.columns import CORRUPT, Columns, bounded_fields, floats
from compd.store.schema import RecorderError

if TYPE_CHECKING:
    import sqlite3
    from pathlib import Path


class AxisReads:
    """The ``axes`` reads of `compd.store.reader.RecorderReader`, which gives the
    connection, the statement deadline and the checks these use."""

    if TYPE_CHECKING:
        path: Path

        def _connection(self) -> sqlite3.Connection: ...
        def _timed(self, what: str) -> AbstractContextManager[None]: ...
        def _seq_span(self, since: float | None, until: float | None
                      ) -> tuple[int, int] | None: ...
        def _refuse_long(self, rows: list[Any], which: str) -> None: ...
        def _joined(self, conn: sqlite3.Connection, table: str, fields: Sequence[str],
                    order_by: str, what: str) -> list[Any]: ...

    def axes(self) -> Columns:
        """Every ``[output.axes]`` axis's row (the ``axes`` table), oldest first, with its
        sample's clock: ``seq`` (int64), ``mono_s``, ``axis``, ``state``, ``cause`` (str),
        ``in_force`` (bool), the value's and slope's stage, sent, confirmed and model
        values, the reference, and for an axis written at its read position the
        ``position_mm`` and the ``offset_um`` written at it (float64, NaN where none:
        `compd.store.schema.AXIS_COLUMNS`). A file
        without per-axis outputs, or from before they were recorded: empty columns."""
        conn = self._connection()
        fields = ("axes.seq", "samples.mono_s", *axis_fields(self._axis_table(conn)))
        try:
            rows = self._joined(conn, "axes", fields, "axes.seq, axes.axis", "axis")
            return {"seq": np.array([r[0] for r in rows], dtype=np.int64),
                    "mono_s": floats(r[1] for r in rows), **axis_columns(rows, 2)}
        except CORRUPT as exc:
            raise RecorderError(self.path, f"corrupt axis rows ({type(exc).__name__}); "
                                "not a recorder compd wrote") from None

    def _axis_table(self, conn: sqlite3.Connection) -> set[str]:
        """The ``axes`` table's columns (none when the file has no such table)."""
        with self._timed("cannot read its axes"):
            return {str(r[1]) for r in conn.execute("PRAGMA table_info(axes)")}

    def axis_names(self, since: float | None = None, until: float | None = None
                   ) -> tuple[str, ...]:
        """The axes with a row among the samples stamped in [since, until), in
        `known_axes` order: one pass over the ``axes`` key's index inside SQLite.
        RecorderError naming the first name that is no axis, or when the table has
        no index on ``seq`` (a file compd did not write: `axis_batch` would scan
        it whole for every batch); none when the file has no ``axes`` table."""
        conn = self._connection()
        if not self._axis_table(conn):
            return ()
        span = self._seq_span(since, until)
        if span is None:
            return ()
        known = known_axes()
        with self._timed("cannot read its axes"):  # a few names, each cut short
            if not any(_first_column(conn, str(index[1])) == "seq"
                       for index in conn.execute("PRAGMA index_list(axes)")):
                # each batch's rows would be a scan of the whole table
                raise RecorderError(self.path, "its axes table has no key on seq; not a "
                                    "recorder compd wrote")
            found = [r[0] for r in conn.execute(
                "SELECT DISTINCT substr(axis, 1, 41) FROM axes WHERE seq BETWEEN ? AND ?"
                " LIMIT ?", (*span, len(known) + 1))]
        bad = sorted((n for n in found if n not in known), key=str)
        if bad:
            shown = repr(bad[0]) if len(str(bad[0])) <= 40 else f"{str(bad[0])[:40]!r}…"
            raise RecorderError(self.path, f"axis rows name {shown}, not an axis (one of "
                                f"{', '.join(known)}); not a recorder compd wrote")
        return tuple(a for a in known if a in found)

    def axis_batch(self, first_seq: int, last_seq: int, axes: Sequence[str]) -> Columns:
        """The rows of `axes` of the samples ``seq`` `first_seq` … `last_seq` (one
        export batch's), ordered by seq and axis: ``seq`` (int64) and `AXIS_COLUMNS`
        (`compd.store.axis_columns`). A key range of the ``axes`` index: memory is the
        batch's rows."""
        conn = self._connection()
        fields = ("axes.seq", *axis_fields(self._axis_table(conn)))
        marks = ", ".join("?" * len(axes))
        with self._timed("cannot read its axes"):
            rows: list[Any] = conn.execute(
                f"SELECT axes.seq, {bounded_fields(fields)} FROM axes WHERE axes.seq"
                f" BETWEEN ? AND ? AND axes.axis IN ({marks}) ORDER BY axes.seq, axes.axis",
                (first_seq, last_seq, *axes)).fetchall()
        self._refuse_long(rows, "axis seq")
        try:
            return {"seq": np.array([r[1] for r in rows], dtype=np.int64),
                    **axis_columns([r[1:-1] for r in rows], 1)}
        except CORRUPT as exc:
            raise RecorderError(self.path, f"corrupt axis rows near seq {first_seq} "
                                f"({type(exc).__name__}); not a recorder compd wrote") from None


def _first_column(conn: sqlite3.Connection, index: str) -> str | None:
    """The first column of the index named `index` (None: an expression)."""
    row = conn.execute("SELECT name FROM pragma_index_info(?) WHERE seqno = 0",
                       (index,)).fetchone()
    return None if row is None or row[0] is None else str(row[0])
