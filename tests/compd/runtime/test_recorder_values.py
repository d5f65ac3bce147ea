"""The recorder's channel values, stored once, as numbers (the view
channel_values) for SQL and Grafana, retention applied to them too, databases
of older compd versions (the first layout; the previous one with the values
twice) read, upgraded and appended to, and the bounded default retention."""

from __future__ import annotations

import contextlib
import json
import math
import sqlite3
from pathlib import Path
from typing import Any

import numpy as np

from compd.config.loader import load_config
from compd.runtime.recorder import Recorder, RecordRow, read_samples
from tests.compd.runtime.test_recorder import _row
from tests.compd.store.recorder_layouts import (
    PREVIOUS,
    PREVIOUS_INSERT,
    PREVIOUS_INSERT_VALUE,
    PREVIOUS_PURGE_VALUES,
    previous_rows,
    write_first,
    write_previous,
)
from tests.configs import MINIMAL


def _rows(path: Path, sql: str, *args: object) -> list[tuple[Any, ...]]:  # SQLite's values
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


def test_a_database_of_the_first_layout_opens_reads_and_appends(tmp_path: Path) -> None:
    path = tmp_path / "old.sqlite"
    write_first(path, [(float(i), {"t_spindle_c": 30.0 + i, "t_ambient_c": 21.5})
                       for i in range(3)])
    before = read_samples(path)
    np.testing.assert_array_equal(before["t_spindle_c"], [30.0, 31.0, 32.0])
    with Recorder(path, commit_every=1) as rec:
        rec.record(_row(7))
    cols = read_samples(path)
    assert cols["seq"].tolist() == [1, 2, 3, 4]
    np.testing.assert_array_equal(cols["t_spindle_c"], [30.0, 31.0, 32.0, 27.0])
    assert cols["valid.t_spindle_c"].all()
    # every row's values are numbers through the view, the older ones too
    assert _rows(path, "SELECT seq, value FROM channel_values WHERE channel='t_spindle_c'") \
        == [(1, 30.0), (2, 31.0), (3, 32.0), (4, 27.0)]


def _previous_rows(n: int) -> list[RecordRow]:
    rows = [_row(i) for i in range(n)]
    rows[3] = RecordRow(3, 3.0, 1.0e9 + 3, None, None, "hold", False,
                        channels={"t_spindle_c": None, "t_ambient_c": 21.5},
                        validity={"t_spindle_c": "stale", "t_ambient_c": None},
                        contributions={})
    return rows


def test_a_database_of_the_previous_layout_reads_as_before_and_is_upgraded(
        tmp_path: Path) -> None:
    """The values twice (JSON and table channel_values): read as they are, then
    upgraded by the recorder that opens it: the table gives way to the view, no
    value lost, and new rows store their values once."""
    path = tmp_path / "previous.sqlite"
    write_previous(path, _previous_rows(6))
    before = read_samples(path)  # read without an upgrade: the reader understands both
    assert before["seq"].tolist() == [1, 2, 3, 4, 5, 6]
    assert math.isnan(before["t_spindle_c"][3]) and not before["valid.t_spindle_c"][3]
    assert before["contribution.spindle"][2] == -0.8
    values = _rows(path, "SELECT seq, channel, value, validity FROM channel_values"
                         " ORDER BY seq, channel")
    with Recorder(path, commit_every=1) as rec:
        rec.record(_row(6))
    after = read_samples(path)
    for name, col in before.items():
        np.testing.assert_array_equal(after[name][:6], col)
    assert _rows(path, "SELECT type FROM sqlite_schema WHERE name = 'channel_values'") \
        == [("view",)]
    assert _rows(path, "SELECT seq, channel, value, validity FROM channel_values"
                       " WHERE seq <= 6 ORDER BY seq, channel") == values
    assert _rows(path, "SELECT validity FROM samples WHERE seq = 7") == [("{}",)]
    assert json.loads(str(_rows(path, "SELECT value FROM meta WHERE key = 'terms'")[0][0])) \
        == ["spindle", "ambient"]


def test_an_older_compd_still_writes_and_purges_an_upgraded_database(tmp_path: Path) -> None:
    """A downgrade: the previous recorder's own statements on the upgraded file
    do not fail (the view's triggers take them), its rows are read."""
    path = tmp_path / "rec.sqlite"
    with Recorder(path, commit_every=1) as rec:
        rec.record(_row(0))
    with contextlib.closing(sqlite3.connect(path, isolation_level=None)) as conn:
        conn.executescript(PREVIOUS)  # its CREATE ... IF NOT EXISTS: the view stands
        sample, values = previous_rows(2, _row(1))
        conn.execute("BEGIN")
        conn.execute(PREVIOUS_INSERT, sample)
        conn.executemany(PREVIOUS_INSERT_VALUE, values)
        conn.execute(PREVIOUS_PURGE_VALUES, (1,))
        conn.execute("COMMIT")
    cols = read_samples(path)
    assert cols["seq"].tolist() == [1, 2] and cols["t_spindle_c"].tolist() == [20.0, 21.0]
    assert _rows(path, "SELECT COUNT(*) FROM channel_values") == [(4,)]


def test_values_are_stored_once(tmp_path: Path) -> None:
    path = tmp_path / "rec.sqlite"
    with Recorder(path, commit_every=2) as rec:
        for i in range(4):
            rec.record(_row(i))
    assert _rows(path, "SELECT name FROM sqlite_schema WHERE type = 'table' ORDER BY name") \
        == [("axes",), ("meta",), ("probes",), ("samples",)]
    # validity names only refused channels (none here); the values are in the JSON alone
    assert _rows(path, "SELECT DISTINCT validity FROM samples") == [("{}",)]


def test_default_retention_is_bounded(tmp_path: Path) -> None:
    p = tmp_path / "compd.toml"
    p.write_text(MINIMAL, encoding="utf-8")
    assert load_config(p).raw.recorder.retention_days == 30.0
    from compd.runtime.daemon import Daemon

    daemon = Daemon(load_config(p))
    daemon.recorder.open_now(daemon.running.cfg)
    try:
        assert daemon.recorder.recorder is not None
        assert daemon.recorder.recorder.keep_rows == math.ceil(30 * 86400 / 1.0)
    finally:
        daemon.recorder.close_now()
    p.write_text(MINIMAL + "\n[recorder]\nretention_days = 0\n", encoding="utf-8")
    keep_all = Daemon(load_config(p))
    keep_all.recorder.open_now(keep_all.running.cfg)
    try:
        kept = keep_all.recorder.recorder
        assert kept is not None and kept.keep_rows is None
    finally:
        keep_all.recorder.close_now()
