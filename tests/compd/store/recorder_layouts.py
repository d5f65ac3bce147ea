"""Recorder databases as older compd versions wrote them, for the tests that
read and upgrade them: built with plain sqlite3 and the older DDL and row
encoding copied here (never with today's recorder), so they stay what those
versions left on disk.

- `FIRST`: ``samples`` without ``attempted_um``/``complete``, no
  ``channel_values``, ``meta`` with ``channels`` only.
- `PREVIOUS`: the layout before the values were stored once: every channel's
  value in the JSON column and again as a row of table ``channel_values``,
  ``validity`` JSON listing every channel (null when valid), no ``terms`` in
  ``meta``.
"""

from __future__ import annotations

import contextlib
import json
import math
import sqlite3
from pathlib import Path
from typing import Any

from compd.core.record import RecordRow

FIRST = """
CREATE TABLE samples (seq INTEGER PRIMARY KEY, cycle INTEGER, mono_s REAL NOT NULL,
    wall_s REAL NOT NULL, offset_um REAL, model_um REAL, state TEXT NOT NULL,
    valid INTEGER NOT NULL, channels TEXT NOT NULL, validity TEXT NOT NULL,
    contributions TEXT NOT NULL);
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
"""

PREVIOUS = """
CREATE TABLE IF NOT EXISTS samples (
    seq INTEGER PRIMARY KEY, cycle INTEGER, mono_s REAL NOT NULL, wall_s REAL NOT NULL,
    offset_um REAL, model_um REAL, state TEXT NOT NULL, valid INTEGER NOT NULL,
    channels TEXT NOT NULL, validity TEXT NOT NULL, contributions TEXT NOT NULL,
    attempted_um REAL, complete INTEGER);
CREATE INDEX IF NOT EXISTS samples_wall_s ON samples (wall_s);
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS channel_values (
    seq INTEGER NOT NULL, channel TEXT NOT NULL, value REAL, validity TEXT,
    PRIMARY KEY (seq, channel)) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS probes (
    seq INTEGER PRIMARY KEY, counter REAL, value_um REAL, measured_um REAL, model_um REAL,
    innovation_um REAL, innovation_sigma_um REAL, accepted INTEGER NOT NULL, reason TEXT,
    bias_um REAL, bias_sigma_um REAL, mode TEXT);
"""

#: the previous recorder's statements, as it ran them on every commit and purge
PREVIOUS_INSERT = ("INSERT INTO samples (seq, cycle, mono_s, wall_s, offset_um, model_um, state,"
                   " valid, channels, validity, contributions, attempted_um, complete)"
                   " VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)")
PREVIOUS_INSERT_VALUE = ("INSERT INTO channel_values (seq, channel, value, validity)"
                         " VALUES (?, ?, ?, ?)")
PREVIOUS_PURGE_VALUES = ("DELETE FROM channel_values WHERE seq <"
                         " (SELECT COALESCE(MIN(seq), ?) FROM samples)")


def _num(value: float | None) -> float | None:
    return None if value is None or not math.isfinite(value) else float(value)


def previous_rows(seq: int, row: RecordRow) -> tuple[tuple[Any, ...],
                                                     list[tuple[Any, ...]]]:
    """One cycle as the previous recorder encoded it: the samples row, and its
    channel_values rows."""
    sample = (seq, row.seq, row.mono_s, row.wall_s, _num(row.offset_um), _num(row.model_um),
              row.state, 1 if row.valid else 0,
              json.dumps({k: _num(v) for k, v in row.channels.items()}, separators=(",", ":")),
              json.dumps({k: (None if v is None else str(v)) for k, v in row.validity.items()},
                         separators=(",", ":")),
              json.dumps({k: _num(v) for k, v in row.contributions.items()},
                         separators=(",", ":")),
              _num(row.attempted_um), 1 if row.complete else 0)
    values = [(seq, name, _num(v), row.validity.get(name)) for name, v in row.channels.items()]
    return sample, values


def write_previous(path: Path, rows: list[RecordRow]) -> None:
    """A database as the previous recorder left it after recording `rows`."""
    with contextlib.closing(sqlite3.connect(path)) as conn:
        conn.execute("PRAGMA journal_mode=WAL")
        conn.executescript(PREVIOUS)
        names: list[str] = []
        for i, row in enumerate(rows):
            sample, values = previous_rows(i + 1, row)
            conn.execute(PREVIOUS_INSERT, sample)
            conn.executemany(PREVIOUS_INSERT_VALUE, values)
            names += [n for n in row.channels if n not in names]
        conn.execute("INSERT INTO meta (key, value) VALUES ('channels', ?)", (json.dumps(names),))
        conn.commit()


def write_first(path: Path, rows: list[tuple[float, dict[str, float | None]]]) -> None:
    """A database of the first layout: (mono_s, channels) per row, all valid."""
    with contextlib.closing(sqlite3.connect(path)) as conn:
        conn.executescript(FIRST)
        for i, (mono_s, channels) in enumerate(rows):
            conn.execute("INSERT INTO samples VALUES (?, ?, ?, ?, ?, ?, 'ok', 1, ?, ?, '{}')",
                         (i + 1, i, mono_s, 1.0e9 + i, 1.0, 1.0, json.dumps(channels),
                          json.dumps(dict.fromkeys(channels))))
        names = list(dict.fromkeys(n for _, c in rows for n in c))
        conn.execute("INSERT INTO meta VALUES ('channels', ?)", (json.dumps(names),))
        conn.commit()
