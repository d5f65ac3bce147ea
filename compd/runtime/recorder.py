"""The sample recorder: every cycle's inputs, validity, per-term contributions,
model output, written offset and fault state in one SQLite database (WAL).

Durability: rows are buffered and committed every `commit_every` rows, in WAL
mode with synchronous=NORMAL: a committed row survives a kill -9 of the
daemon (it is in the OS's page cache), so a crash loses at most the rows of
the last commit interval; the database is always readable (SQLite's WAL
recovery). A power cut may lose the last commits as well, never consistency.

The recorder never stops compensation: `record()` and `flush()` never raise.
When a commit fails (disk full, I/O error, a locked database), its rows are
dropped and counted, `alarm` turns True and `last_error` says why; the next
commit that succeeds clears the alarm.

Schema (table ``samples``): ``seq`` INTEGER PRIMARY KEY, numbered by the
recorder itself (contiguous, continuing across restarts: MAX(seq)+1), ``cycle``
(the daemon's own cycle number, `RecordRow.seq`, may repeat after a restart),
``mono_s``, ``wall_s``, ``offset_um`` (written and confirmed by the controller;
NULL when no offset was sent or the write failed), ``attempted_um`` (the
offset sent, confirmed or not), ``model_um``, ``state`` (the
fault state), ``valid`` (0/1: inputs valid, model stepped), ``complete`` (0/1:
the cycle is complete as `compd.core.cycle.offset_in_force` defines it, the
offset compd wants is in force; a held output's cycles are valid, never
complete; NULL in rows of an older compd), and three JSON objects: ``channels`` {name:
value}, ``validity`` {name: reason or null}, ``contributions`` {term: µm}.
Non-finite floats are stored as JSON null (read back as NaN).

Table ``channel_values`` holds the same channel values as numbers a SQL or
Grafana user can query without JSON: one row per sample and channel,
(``seq``, ``channel``, ``value`` REAL (NULL when missing or non-finite),
``validity`` (NULL when valid, else the reason)), keyed by (seq, channel);
``seq`` joins ``samples``. Rows of a database written by an older compd
(before this table) keep their values in the JSON column only (SQLite's
``json_extract(channels, '$.bearing')`` reads them); such a database opens,
reads and is appended to as before.

Retention (`keep_rows`) keeps the newest rows by ``seq``, the recorder's own
numbering: `recorder.retention_days` (30 by default, 0 keeps everything)
becomes days × 86400 / period_s rows; ``channel_values`` follows ``samples``.
No clock decides what is deleted. Table ``meta``
(key, value) holds ``channels``: a JSON list of every channel name seen.

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

`read_samples` turns a database into numpy columns for `compd fit` and
`compd replay`.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import sqlite3
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from compd.core.record import RecordRow
from compd.errors import CompdError
from compd.runtime.statedir import StateDir, StateDirError

__all__ = ["FIXED_COLUMNS", "RecordRow", "Recorder", "RecorderError", "read_samples"]

_SCHEMA = """
CREATE TABLE IF NOT EXISTS samples (
    seq INTEGER PRIMARY KEY,
    cycle INTEGER,
    mono_s REAL NOT NULL,
    wall_s REAL NOT NULL,
    offset_um REAL,
    model_um REAL,
    state TEXT NOT NULL,
    valid INTEGER NOT NULL,
    channels TEXT NOT NULL,
    validity TEXT NOT NULL,
    contributions TEXT NOT NULL,
    attempted_um REAL,
    complete INTEGER
);
CREATE INDEX IF NOT EXISTS samples_wall_s ON samples (wall_s);
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS channel_values (
    seq INTEGER NOT NULL,
    channel TEXT NOT NULL,
    value REAL,
    validity TEXT,
    PRIMARY KEY (seq, channel)
) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS probes (
    seq INTEGER PRIMARY KEY,
    counter REAL,
    value_um REAL,
    measured_um REAL,
    model_um REAL,
    innovation_um REAL,
    innovation_sigma_um REAL,
    accepted INTEGER NOT NULL,
    reason TEXT,
    bias_um REAL,
    bias_sigma_um REAL,
    mode TEXT
);
"""

_INSERT = ("INSERT INTO samples (seq, cycle, mono_s, wall_s, offset_um, model_um, state, valid,"
           " channels, validity, contributions, attempted_um, complete)"
           " VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)")

_INSERT_VALUE = "INSERT INTO channel_values (seq, channel, value, validity) VALUES (?, ?, ?, ?)"

#: a probe's columns ([adaptation]): the sample's seq, then `RecordRow.probe`'s fields
PROBE_COLUMNS = ("counter", "value_um", "measured_um", "model_um", "innovation_um",
                 "innovation_sigma_um", "accepted", "reason", "bias_um", "bias_sigma_um", "mode")
_INSERT_PROBE = (f"INSERT INTO probes (seq, {', '.join(PROBE_COLUMNS)})"
                 f" VALUES ({', '.join('?' * (len(PROBE_COLUMNS) + 1))})")

#: Columns `read_samples` always returns; channel names may not collide with them.
FIXED_COLUMNS = ("seq", "cycle", "time_s", "mono_s", "wall_s", "offset_um", "model_um", "valid",
                 "state")

#: SQLite page cache of the recorder's connection, KiB. The recorder only appends
#: (the rightmost pages of the table and of its wall_s index) and purges from the
#: left (by seq), so a few dozen pages hold its working set; SQLite's default (2000 KiB)
#: only makes the daemon's resident memory creep up by ~2 MB over the first
#: machine hours as the cache fills with pages never read again.
CACHE_KIB = 256


class RecorderError(CompdError):
    """The recorder database cannot be opened or read. `path` is the file."""

    def __init__(self, path: Path, reason: str) -> None:
        self.path = path
        self.reason = reason
        super().__init__(f"recorder {path}: {reason}")


def _num(value: float | None) -> float | None:
    """A float for SQLite/JSON; non-finite and missing become NULL/null."""
    if value is None:
        return None
    v = float(value)
    return v if math.isfinite(v) else None


def _json_numbers(values: Mapping[str, float | None]) -> str:
    return json.dumps({str(k): _num(v) for k, v in values.items()}, allow_nan=False,
                      separators=(",", ":"))


def _tuple(seq: int, row: RecordRow) -> tuple[Any, ...]:
    return (seq, row.seq, float(row.mono_s), float(row.wall_s), _num(row.offset_um),
            _num(row.model_um), str(row.state), 1 if row.valid else 0,
            _json_numbers(row.channels),
            json.dumps({str(k): (None if v is None else str(v))
                        for k, v in row.validity.items()}, separators=(",", ":")),
            _json_numbers(row.contributions), _num(row.attempted_um),
            1 if row.complete else 0)


def _value_rows(seq: int, row: RecordRow) -> list[tuple[Any, ...]]:
    return [(seq, str(name), _num(value),
             None if (why := row.validity.get(name)) is None else str(why))
            for name, value in row.channels.items()]


class Recorder:
    """Buffered SQLite sample recorder (see the module docstring).

    Counters: `committed` rows committed by this instance, `dropped` rows lost
    (failed commits, or recorded while not open), `last_error` the latest
    failure, `alarm` True while writes fail.
    """

    def __init__(self, path: Path, *, commit_every: int = 10, keep_rows: int | None = None,
                 purge_every_commits: int = 100) -> None:
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
        self._commits_since_purge = 0

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
            mode = conn.execute("PRAGMA journal_mode=WAL").fetchone()[0]
            if str(mode).lower() != "wal":
                raise RecorderError(self.path, f"WAL mode refused (journal_mode={mode})")
            conn.execute("PRAGMA synchronous=NORMAL")
            conn.execute(f"PRAGMA cache_size=-{CACHE_KIB}")
            conn.executescript(_SCHEMA)
            columns = {r[1] for r in conn.execute("PRAGMA table_info(samples)")}
            if "attempted_um" not in columns:  # a database of an older compd
                conn.execute("ALTER TABLE samples ADD COLUMN attempted_um REAL")
            if "complete" not in columns:  # older rows: NULL (not known)
                conn.execute("ALTER TABLE samples ADD COLUMN complete INTEGER")
            last = conn.execute("SELECT MAX(seq) FROM samples").fetchone()[0]
            meta = conn.execute("SELECT value FROM meta WHERE key='channels'").fetchone()
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
        self._channels = list(json.loads(meta[0])) if meta else []
        self._conn = conn

    def record(self, row: RecordRow) -> None:
        """Buffer one row; commit when `commit_every` rows are waiting. Never raises."""
        if self._conn is None:
            self.dropped += 1
            self.alarm = True
            self.last_error = "recorder is not open"
            return
        self._buffer.append(row)
        if len(self._buffer) >= self.commit_every:
            self.flush()

    def flush(self) -> None:
        """Commit the buffered rows now. Never raises: a failure drops and counts them."""
        rows, self._buffer = self._buffer, []
        if not rows:
            return
        conn = self._conn
        if conn is None:
            self._fail(len(rows), "recorder is not open")
            return
        try:
            self._check(self._dir)
        except StateDirError as exc:  # a name swapped under us: SQLite must not write
            self._fail(len(rows), f"refused: {exc}")
            return
        first = self._next_seq
        known = set(self._channels)
        new = list(dict.fromkeys(str(n) for r in rows for n in r.channels if n not in known))
        names = self._channels + new
        try:
            conn.execute("BEGIN IMMEDIATE")
            conn.executemany(_INSERT, [_tuple(first + i, r) for i, r in enumerate(rows)])
            conn.executemany(_INSERT_VALUE, [v for i, r in enumerate(rows)
                                             for v in _value_rows(first + i, r)])
            conn.executemany(_INSERT_PROBE, [
                (first + i, *(r.probe.get(c) for c in PROBE_COLUMNS))
                for i, r in enumerate(rows) if r.probe is not None])
            if new:
                conn.execute("INSERT OR REPLACE INTO meta (key, value) VALUES ('channels', ?)",
                             (json.dumps(names),))
            conn.execute("COMMIT")
        except (sqlite3.Error, OSError, ValueError) as exc:
            self._rollback(conn)
            self._fail(len(rows), f"{type(exc).__name__}: {exc}")
            return
        if new:
            self._channels = names
        self._next_seq = first + len(rows)
        self.committed += len(rows)
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
            conn.execute("DELETE FROM channel_values WHERE seq <"
                         " (SELECT COALESCE(MIN(seq), ?) FROM samples)", (last_dropped_seq + 1,))
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


def _nan_floats(values: list[float | None]) -> npt.NDArray[np.float64]:
    return np.array([np.nan if v is None else v for v in values], dtype=np.float64)


def read_samples(path: Path) -> dict[str, npt.NDArray[Any]]:
    """Every sample of a recorder database as numpy columns, in seq order.

    Columns (all of equal length): ``seq`` and ``cycle`` (int64; cycle -1 when
    the daemon gave none), ``time_s`` (float64: the daemon's sample clock,
    the same as ``mono_s``; it restarts with the daemon's clock), ``mono_s``,
    ``wall_s``, ``offset_um`` (written), ``model_um``, ``valid`` (bool),
    ``state`` (str), then one float64 column per channel named as the channel
    (NaN where missing or non-finite), ``valid.<channel>`` (bool: a finite value
    and no invalidity reason recorded) and ``contribution.<term>`` (float64) per model term.
    Raises RecorderError when the file is missing or not a recorder database.
    """
    path = Path(path)
    if not path.exists():
        raise RecorderError(path, "no such file")
    try:
        conn = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    except sqlite3.Error as exc:
        raise RecorderError(path, f"cannot open: {exc}") from exc
    try:
        meta = conn.execute("SELECT value FROM meta WHERE key='channels'").fetchone()
        rows = conn.execute(
            "SELECT seq, cycle, mono_s, wall_s, offset_um, model_um, state, valid, channels,"
            " validity, contributions FROM samples ORDER BY seq").fetchall()
    except sqlite3.Error as exc:
        raise RecorderError(path, f"not a recorder database: {exc}") from exc
    finally:
        conn.close()
    names: list[str] = list(json.loads(meta[0])) if meta else []
    clash = sorted(set(names).intersection(FIXED_COLUMNS))
    if clash:
        raise RecorderError(path, f"channel name(s) {clash} collide with fixed columns")
    channels = [json.loads(r[8]) for r in rows]
    validity = [json.loads(r[9]) for r in rows]
    contributions = [json.loads(r[10]) for r in rows]
    terms = list(dict.fromkeys(t for c in contributions for t in c))
    mono = _nan_floats([r[2] for r in rows])
    out: dict[str, npt.NDArray[Any]] = {
        "seq": np.array([r[0] for r in rows], dtype=np.int64),
        "cycle": np.array([-1 if r[1] is None else r[1] for r in rows], dtype=np.int64),
        "time_s": mono,
        "mono_s": mono.copy(),
        "wall_s": _nan_floats([r[3] for r in rows]),
        "offset_um": _nan_floats([r[4] for r in rows]),
        "model_um": _nan_floats([r[5] for r in rows]),
        "valid": np.array([bool(r[7]) for r in rows], dtype=bool),
        "state": np.array([r[6] for r in rows], dtype=str),
    }
    for name in names:
        out[name] = _nan_floats([c.get(name) for c in channels])
        out[f"valid.{name}"] = np.array(
            [c.get(name) is not None and v.get(name) is None
             for c, v in zip(channels, validity, strict=True)], dtype=bool)
    for term in terms:
        out[f"contribution.{term}"] = _nan_floats([c.get(term) for c in contributions])
    return out


def read_probes(path: Path) -> dict[str, npt.NDArray[Any]]:
    """Every probe of a recorder database, in seq order, with its sample's clock.

    Columns (equal length): ``seq`` (int64), ``mono_s`` (float64: the daemon's sample
    clock at the probe's cycle; it restarts with the daemon), ``measured_um`` and
    ``model_um`` (float64, NaN where none was recorded), ``reason`` (str: "" for an
    accepted probe, else why it was refused). Raises RecorderError when the file is not
    a recorder database (a database from before probes were recorded has none: empty).
    """
    path = Path(path)
    if not path.exists():
        raise RecorderError(path, "no such file")
    try:
        conn = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    except sqlite3.Error as exc:
        raise RecorderError(path, f"cannot open: {exc}") from exc
    try:
        rows = conn.execute(
            "SELECT p.seq, s.mono_s, p.measured_um, p.model_um, p.accepted, p.reason"
            " FROM probes p JOIN samples s ON s.seq = p.seq ORDER BY p.seq").fetchall()
    except sqlite3.Error as exc:
        raise RecorderError(path, f"not a recorder database with probes: {exc}") from exc
    finally:
        conn.close()
    return {
        "seq": np.array([r[0] for r in rows], dtype=np.int64),
        "mono_s": _nan_floats([r[1] for r in rows]),
        "measured_um": _nan_floats([r[2] for r in rows]),
        "model_um": _nan_floats([r[3] for r in rows]),
        "reason": np.array(["" if r[4] else str(r[5] or "refused") for r in rows], dtype=str),
    }
