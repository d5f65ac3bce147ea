"""The sample recorder: every cycle's inputs, validity, per-term contributions,
model output, written offset and fault state in one SQLite database (WAL).

Durability: rows are buffered and committed every `commit_every` rows, in WAL
mode with synchronous=NORMAL: a committed row survives a kill -9 of the
daemon (it is in the OS's page cache), so a crash loses at most the rows of
the last commit interval; the database is always readable (SQLite's WAL
recovery). A power cut may lose the last commits as well, never consistency.

With a `writer` (`compd.runtime.diskwriter`; the daemon gives the process's),
a batch of `commit_every` rows is formatted on the caller's thread
(`compd.runtime.recorder_rows`) and committed on the writer's, so the loop
does not wait for SQLite; the next row
is buffered only once that batch is committed (the caller waits for it then,
which happens only on a disk slower than a cycle), so no more rows are ever
uncommitted than without a writer: a crash still loses at most the last
commit interval. `flush()` and `close()` commit
on the caller's thread after the batch in flight. Without a writer every
commit is the caller's, as a tool that records offline wants.

The recorder never stops compensation: `record()` and `flush()` never raise.
When a commit fails (disk full, I/O error, a locked database), its rows are
dropped and counted, `alarm` turns True and `last_error` says why; the next
commit that succeeds clears the alarm.

The file's layout is `compd.store.schema`'s (one row per cycle in table
``samples``: the recorder's own contiguous ``seq``, continuing across restarts
as MAX(seq)+1, the daemon's ``cycle``, the times, ``offset_um`` as confirmed by
the controller and ``attempted_um`` as sent, ``model_um``, ``state``,
``valid``, ``complete``, and the JSON objects ``channels``, ``validity`` and
``contributions``; non-finite floats stored as null). Each channel value is
stored once, in the JSON column; the ``channel_values`` view shows them as
numbers. With ``[output.axes]`` each sample has one row per axis in table
``axes`` (its state, cause, in force, and its value's and slope's stage,
sent, confirmed and model values; an axis written at its read position adds
that position and the offset written at it), purged with its sample. Opening a file
an older compd wrote upgrades it (`compd.store.schema.upgrade`); it then
reads and is appended to as before.

Retention (`keep_rows`) keeps the newest rows by ``seq``, the recorder's own
numbering: `recorder.retention_days` (30 by default, 0 keeps everything)
becomes days × 86400 / period_s rows. No clock decides what is deleted. Table
``meta`` (key, value) holds ``channels`` and ``terms``: JSON lists of every
channel and model term seen.

Files: SQLite opens the database and its ``-wal``, ``-shm`` and ``-journal``
by name, so the recorder opens their directory first (`StateDir`: created
0700 with parents 0755; it and its parents owned by root or us and not
writable by group or others unless sticky) and, before
SQLite opens them and again before every commit, checks under that
descriptor that none of the four names is a symbolic link, a hard link
(st_nlink > 1: SQLite would overwrite the other name's file) or not a
regular file of ours, and that the path still names the directory it opened.
Refused at open: RecorderError; refused later: the commit is dropped and
counted like any failed one (alarm, `last_error` says why).

Reading is `compd.store.reader`'s (`RecorderReader`, `read_samples`), which
this module re-exports for its older callers.
"""

from __future__ import annotations

import contextlib
import json
import os
import sqlite3
from collections.abc import Callable
from concurrent.futures import Future
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

from compd.core.record import RecordRow
from compd.runtime.recorder_rows import Batch
from compd.runtime.statedir import StateDir, StateDirError
from compd.store.reader import read_samples
from compd.store.schema import (
    CHANNELS_KEY,
    FIXED_COLUMNS,
    INSERT_AXIS,
    INSERT_PROBE,
    INSERT_SAMPLE,
    TERMS_KEY,
    RecorderError,
    meta_names,
    upgrade,
)

if TYPE_CHECKING:
    from compd.runtime.diskwriter import DiskWriter

__all__ = ["FIXED_COLUMNS", "RecordRow", "Recorder", "RecorderError", "read_samples"]

T = TypeVar("T")

#: SQLite page cache of the recorder's connection, KiB. The recorder only appends
#: (the rightmost pages of the table and of its wall_s index) and purges from the
#: left (by seq), so a few dozen pages hold its working set; SQLite's default (2000 KiB)
#: only makes the daemon's resident memory creep up by ~2 MB over the first
#: machine hours as the cache fills with pages never read again.
CACHE_KIB = 256
#: SQLite page size of a file the recorder creates (a file already there keeps
#: its own). Each commit writes the pages it touched to the WAL, whole, and the
#: checkpoint writes them again: a commit of 10 rows of ~300 B with 4 KiB pages
#: wrote 2.0 KB per row, with 1 KiB pages 1.15 KB (the file 9 % larger, read as
#: fast: benchmarks/bench_daemon_fleet.py reports the bytes per cycle).
PAGE_BYTES = 1024


class Recorder:
    """Buffered SQLite sample recorder (see the module docstring).

    Counters: `committed` rows committed by this instance, `dropped` rows lost
    (failed commits, or recorded while not open), `last_error` the latest
    failure, `alarm` True while writes fail.
    """

    def __init__(self, path: Path, *, commit_every: int = 10, keep_rows: int | None = None,
                 purge_every_commits: int = 100, writer: DiskWriter | None = None) -> None:
        if commit_every < 1:
            raise ValueError(f"commit_every must be >= 1, got {commit_every}")
        if keep_rows is not None and keep_rows < 1:
            raise ValueError(f"keep_rows must be >= 1, got {keep_rows}")
        if purge_every_commits < 1:
            raise ValueError(f"purge_every_commits must be >= 1, got {purge_every_commits}")
        self.path = Path(path)
        self.commit_every = commit_every
        self.keep_rows = keep_rows
        self.purge_every_commits = purge_every_commits
        self.committed = 0
        self.dropped = 0
        self.purged = 0
        self.last_error: str | None = None
        self.alarm = False
        self._conn: sqlite3.Connection | None = None
        self._dir: StateDir | None = None
        self._buffer: list[RecordRow] = []
        self._next_seq = 1
        self._channels: list[str] = []
        self._terms: list[str] = []
        self._commits_since_purge = 0
        self._writer = writer
        #: the batch the writer is committing (None: none)
        self._in_flight: Future[None] | None = None

    @property
    def is_open(self) -> bool:
        return self._conn is not None

    @property
    def pending(self) -> int:
        """Rows recorded but not committed yet."""
        return len(self._buffer)

    def open(self) -> None:
        """Open (or create) the database. Raises RecorderError when it cannot."""
        if self._conn is not None:
            return
        directory: StateDir | None = None
        try:
            directory = StateDir.open(self.path.parent, what="recorder's directory",
                                      private=False)
            self._check(directory)
            # created here 0600 (whatever the umask): SQLite gives -wal and -shm its mode
            os.close(directory.open_file(self.path.name, os.O_RDWR))
            conn = sqlite3.connect(self.path, isolation_level=None, check_same_thread=False)
        except StateDirError as exc:
            if directory is not None:
                directory.close()
            raise RecorderError(self.path, f"cannot open: {exc}") from exc
        except (OSError, sqlite3.Error) as exc:
            if directory is not None:
                directory.close()
            raise RecorderError(self.path, f"cannot open: {exc}") from exc
        try:
            conn.execute(f"PRAGMA page_size={PAGE_BYTES}")  # a new file only
            mode = conn.execute("PRAGMA journal_mode=WAL").fetchone()[0]
            if str(mode).lower() != "wal":
                raise RecorderError(self.path, f"WAL mode refused (journal_mode={mode})")
            conn.execute("PRAGMA synchronous=NORMAL")
            conn.execute(f"PRAGMA cache_size=-{CACHE_KIB}")
            upgrade(conn)  # a file of an older compd: its layout brought to this one
            last = conn.execute("SELECT MAX(seq) FROM samples").fetchone()[0]
            channels = self._meta_names(conn, CHANNELS_KEY)
            terms = self._meta_names(conn, TERMS_KEY)
            self._check(directory)  # SQLite has opened its files by now
        except sqlite3.Error as exc:
            conn.close()
            directory.close()
            raise RecorderError(self.path, f"cannot prepare: {exc}") from exc
        except StateDirError as exc:
            conn.close()
            directory.close()
            raise RecorderError(self.path, f"cannot open: {exc}") from exc
        except RecorderError:
            conn.close()
            directory.close()
            raise
        self._dir = directory
        self._next_seq = (int(last) if last is not None else 0) + 1
        self._channels = channels
        self._terms = terms
        self._conn = conn

    def _meta_names(self, conn: sqlite3.Connection, key: str) -> list[str]:
        try:
            return meta_names(conn, key) or []
        except ValueError as exc:
            raise RecorderError(self.path, f"cannot prepare: {exc}") from None

    def writer_job(self, job: Callable[[], T]) -> Future[T] | None:
        """`job` run on this recorder's disk thread, after its commits handed over
        before (None: no writer)."""
        if self._writer is None:
            return None
        return self._writer.submit(job, key=str(self.path.parent))

    def record(self, row: RecordRow) -> None:
        """Buffer one row; commit when `commit_every` rows are waiting. Never raises."""
        if self._conn is None:
            self.dropped += 1
            self.alarm = True
            self.last_error = "recorder is not open"
            return
        if self._in_flight is not None:
            # the last batch committed before a row joins the next one: never more
            # than one commit interval uncommitted (waits only on a disk slower than
            # a cycle)
            self._settle()
        self._buffer.append(row)
        if len(self._buffer) < self.commit_every:
            return
        if self._writer is None:
            self.flush()
            return
        batch = self._batch()
        if batch is not None:
            self._in_flight = self.writer_job(lambda: self._commit(batch))

    def flush(self) -> None:
        """Commit the buffered rows now (after the batch in flight). Never raises: a
        failure drops and counts them."""
        self._settle()
        batch = self._batch()
        if batch is not None:
            self._commit(batch)

    def _settle(self) -> None:
        """Wait for the batch in flight (committed or failed, as counted)."""
        job, self._in_flight = self._in_flight, None
        if job is not None:
            try:
                job.result()
            except Exception as exc:  # _commit catches what it expects: this is a bug
                self.alarm = True
                self.last_error = f"{type(exc).__name__}: {exc}"

    def _batch(self) -> Batch | None:
        """The buffered rows formatted for one commit (None: none, or not open)."""
        rows, self._buffer = self._buffer, []
        if not rows:
            return None
        if self._conn is None:
            self._fail(len(rows), "recorder is not open")
            return None
        try:
            return Batch.of(self._next_seq, rows, self._channels, self._terms)
        except (ValueError, TypeError, AttributeError) as exc:
            self._fail(len(rows), f"{type(exc).__name__}: {exc}")
            return None

    def _commit(self, batch: Batch) -> None:
        """One transaction of `batch` (on the writer's thread when there is one)."""
        conn = self._conn
        if conn is None:
            self._fail(batch.count, "recorder is not open")
            return
        try:
            self._check(self._dir)
        except StateDirError as exc:  # a name swapped under us: SQLite must not write
            self._fail(batch.count, f"refused: {exc}")
            return
        try:
            conn.execute("BEGIN IMMEDIATE")
            conn.executemany(INSERT_SAMPLE, batch.samples)
            conn.executemany(INSERT_PROBE, batch.probes)
            if batch.axes:
                conn.executemany(INSERT_AXIS, batch.axes)
            for key, names, known in ((CHANNELS_KEY, batch.channels, self._channels),
                                      (TERMS_KEY, batch.terms, self._terms)):
                if len(names) > len(known):
                    conn.execute("INSERT OR REPLACE INTO meta (key, value) VALUES (?, ?)",
                                 (key, json.dumps(names)))
            conn.execute("COMMIT")
        except (sqlite3.Error, OSError, ValueError) as exc:
            self._rollback(conn)
            self._fail(batch.count, f"{type(exc).__name__}: {exc}")
            return
        self._channels, self._terms = batch.channels, batch.terms
        self._next_seq = batch.first + batch.count
        self.committed += batch.count
        self.alarm = False
        self._commits_since_purge += 1
        if self.keep_rows is not None and self._commits_since_purge >= self.purge_every_commits:
            self._commits_since_purge = 0
            self._purge(conn, self._next_seq - 1 - self.keep_rows)

    def _purge(self, conn: sqlite3.Connection, last_dropped_seq: int) -> None:
        """Delete the rows numbered up to `last_dropped_seq`, the oldest first, a
        bounded number per call, so that a large backlog (a retention shortened in
        the config) is worked off over several commits instead of stalling one cycle.

        Retention counts rows on the recorder's own sequence, never a clock: a PC
        whose clock battery died stamps rows in 2000, and correcting the clock
        must not make them look 26 years old (they were all deleted once)."""
        if last_dropped_seq < 1:
            return
        limit = max(1000, 10 * self.purge_every_commits * self.commit_every)
        try:
            cur = conn.execute(
                "DELETE FROM samples WHERE seq IN"
                " (SELECT seq FROM samples WHERE seq <= ? ORDER BY seq LIMIT ?)",
                (last_dropped_seq, limit))
            self.purged += max(cur.rowcount, 0)
            # the axes' rows of the samples gone (the primary key's range)
            conn.execute("DELETE FROM axes WHERE seq < "
                         "(SELECT COALESCE(MIN(seq), ?) FROM samples)", (last_dropped_seq + 1,))
        except sqlite3.Error as exc:
            self._rollback(conn)
            self.last_error = f"retention: {type(exc).__name__}: {exc}"

    def _check(self, directory: StateDir | None) -> None:
        """SQLite opens its files by name: refuse links, hard links and a moved
        directory under those names (StateDirError)."""
        if directory is None:
            return
        name = self.path.name
        directory.check_names(name + suffix for suffix in ("", "-wal", "-shm", "-journal"))
        directory.verify()

    @staticmethod
    def _rollback(conn: sqlite3.Connection) -> None:
        if conn.in_transaction:
            with contextlib.suppress(sqlite3.Error):
                conn.execute("ROLLBACK")

    def _fail(self, n: int, reason: str) -> None:
        self.dropped += n
        self.alarm = True
        self.last_error = reason

    def close(self) -> None:
        """Commit what is buffered and close. Never raises."""
        self.flush()
        conn, self._conn = self._conn, None
        if conn is not None:
            with contextlib.suppress(sqlite3.Error):
                conn.close()
        directory, self._dir = self._dir, None
        if directory is not None:
            directory.close()

    def __enter__(self) -> Recorder:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
