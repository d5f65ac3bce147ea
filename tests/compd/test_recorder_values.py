"""The recorder's channel values as numbers (table channel_values) for SQL and
Grafana, retention applied to them too, a database of an older compd (JSON
columns only) still opening and reading, and the bounded default retention."""

from __future__ import annotations

import contextlib
import json
import math
import sqlite3
from pathlib import Path

import numpy as np

from compd.config.loader import load_config
from compd.runtime.recorder import Recorder, RecordRow, read_samples

from .test_config import BASE
from .test_recorder import _row


def _rows(path: Path, sql: str, *args: object) -> list[tuple[object, ...]]:
    with contextlib.closing(sqlite3.connect(path)) as conn:
        return list(conn.execute(sql, args))


def test_channel_values_are_numbers_a_sql_user_can_query(tmp_path: Path) -> None:
    path = tmp_path / "rec.sqlite"
    with Recorder(path, commit_every=3) as rec:
        for i in range(5):
            rec.record(_row(i))
        rec.record(RecordRow(None, 5.0, 1.0e9 + 5, None, None, "hold", False,
                             channels={"t_spindle_c": float("nan"), "t_ambient_c": 21.5},
                             validity={"t_spindle_c": "stale", "t_ambient_c": None},
                             contributions={}))
    got = _rows(path, "SELECT s.wall_s, v.value, typeof(v.value) FROM samples s"
                      " JOIN channel_values v USING (seq)"
                      " WHERE v.channel = 't_spindle_c' ORDER BY s.seq")
    assert [r[1] for r in got[:5]] == [20.0, 21.0, 22.0, 23.0, 24.0]
    assert {r[2] for r in got[:5]} == {"real"}
    assert got[5][1] is None  # NaN: NULL, with its reason beside it
    assert _rows(path, "SELECT validity FROM channel_values WHERE seq = 6 AND"
                       " channel = 't_spindle_c'") == [("stale",)]
    (avg,) = _rows(path, "SELECT AVG(value) FROM channel_values WHERE channel = 't_ambient_c'")
    assert avg[0] == 21.5


def test_retention_trims_channel_values_with_samples(tmp_path: Path) -> None:
    path = tmp_path / "rec.sqlite"
    with Recorder(path, commit_every=1, keep_rows=10, purge_every_commits=5) as rec:
        for i in range(60):
            rec.record(_row(i))
    (first,) = _rows(path, "SELECT MIN(seq) FROM samples")
    assert first[0] > 1
    assert _rows(path, "SELECT COUNT(*) FROM channel_values WHERE seq < ?", first[0]) == [(0,)]
    (n,) = _rows(path, "SELECT COUNT(*) FROM samples")
    assert _rows(path, "SELECT COUNT(*) FROM channel_values") == [(2 * n[0],)]


_OLD_SCHEMA = """
CREATE TABLE samples (seq INTEGER PRIMARY KEY, cycle INTEGER, mono_s REAL NOT NULL,
    wall_s REAL NOT NULL, offset_um REAL, model_um REAL, state TEXT NOT NULL,
    valid INTEGER NOT NULL, channels TEXT NOT NULL, validity TEXT NOT NULL,
    contributions TEXT NOT NULL);
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
"""


def test_a_database_of_an_older_compd_opens_reads_and_appends(tmp_path: Path) -> None:
    path = tmp_path / "old.sqlite"
    with contextlib.closing(sqlite3.connect(path)) as conn:
        conn.executescript(_OLD_SCHEMA)
        for i in range(3):
            conn.execute("INSERT INTO samples VALUES (?, ?, ?, ?, ?, ?, 'ok', 1, ?, ?, '{}')",
                         (i + 1, i, float(i), 1.0e9 + i, 1.0, 1.0,
                          json.dumps({"t_spindle_c": 30.0 + i, "t_ambient_c": 21.5}),
                          json.dumps({"t_spindle_c": None, "t_ambient_c": None})))
        conn.execute("INSERT INTO meta VALUES ('channels', ?)",
                     (json.dumps(["t_spindle_c", "t_ambient_c"]),))
        conn.commit()
    before = read_samples(path)
    np.testing.assert_array_equal(before["t_spindle_c"], [30.0, 31.0, 32.0])
    with Recorder(path, commit_every=1) as rec:
        rec.record(_row(7))
    cols = read_samples(path)
    assert cols["seq"].tolist() == [1, 2, 3, 4]
    np.testing.assert_array_equal(cols["t_spindle_c"], [30.0, 31.0, 32.0, 27.0])
    assert _rows(path, "SELECT seq, value FROM channel_values WHERE channel='t_spindle_c'") \
        == [(4, 27.0)]
    # the older rows stay queryable through their JSON column
    assert _rows(path, "SELECT json_extract(channels, '$.t_spindle_c') FROM samples"
                       " WHERE seq = 2") == [(31.0,)]


def test_default_retention_is_bounded(tmp_path: Path) -> None:
    p = tmp_path / "compd.toml"
    p.write_text(BASE, encoding="utf-8")
    assert load_config(p).raw.recorder.retention_days == 30.0
    from compd.runtime.daemon import Daemon

    daemon = Daemon(load_config(p))
    daemon.recorder.open_now()
    try:
        assert daemon.recorder.recorder is not None
        assert daemon.recorder.recorder.keep_rows == math.ceil(30 * 86400 / 1.0)
    finally:
        daemon.recorder.recorder.close()
    p.write_text(BASE + "\n[recorder]\nretention_days = 0\n", encoding="utf-8")
    keep_all = Daemon(load_config(p))
    keep_all.recorder.open_now()
    try:
        kept = keep_all.recorder.recorder
        assert kept is not None and kept.keep_rows is None
    finally:
        keep_all.recorder.recorder.close()
