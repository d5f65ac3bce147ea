"""A recorder database is data, never code: a table the reader reads that is a view
(a recursive one hung `compd refine` for a minute and more: read-only mode does not
stop a view) or a virtual table is refused at once; every statement runs against a
deadline; a field past the CSV bound (128 KiB) is refused naming its row and column
before it reaches Python (a 100 MB cell took `compd export` to 1.3 GB and more)."""

from __future__ import annotations

import contextlib
import csv
import json
import sqlite3
from pathlib import Path
from typing import Any

import pytest

from compd.cli import main
from compd.infiles import MAX_FIELD_CHARS
from compd.runtime.recorder import Recorder, RecordRow
from compd.store import reader as store_reader
from compd.store.reader import RecorderReader
from compd.store.schema import RecorderError
from compd.sysexits import EX_DATAERR
from compd.testing import FakeClock
from tests.compd.offline.test_refine import _MODEL

T0 = 1_795_000_000.0


def _recorder(path: Path, n: int = 40, *, probe_every: int = 4) -> Path:
    with Recorder(path, commit_every=10) as rec:
        for k in range(n):
            probe = None
            if k % probe_every == 0:
                probe = {"counter": float(k), "value_um": 1.0, "measured_um": 5.0 + 0.1 * k,
                         "model_um": 5.0, "accepted": True, "reason": None, "mode": "apply"}
            rec.record(RecordRow(seq=k, mono_s=3600.0 * k, wall_s=T0 + k, offset_um=0.0,
                                 model_um=5.0, state="running", valid=True,
                                 channels={"bearing": 20.0}, contributions={"spindle": 1.0},
                                 probe=probe))
    return path


def _sql(path: Path, *statements: str, params: tuple[Any, ...] = ()) -> None:
    with contextlib.closing(sqlite3.connect(path)) as conn:
        for statement in statements:
            conn.execute(statement, params if "?" in statement else ())
        conn.commit()


_ENDLESS = ("WITH RECURSIVE r(x) AS (SELECT 1 UNION ALL SELECT x + 1 FROM r) "
            "SELECT x AS {cols} FROM r ORDER BY x DESC")


@pytest.mark.parametrize(("table", "replacement", "what"), [
    ("probes", "CREATE VIEW probes AS " + _ENDLESS.format(
        cols="seq, 1.0 AS measured_um, 0.0 AS model_um, 1 AS accepted, NULL AS reason"),
     "probes is a view"),
    ("meta", "CREATE VIEW meta AS " + _ENDLESS.format(cols="key, '[]' AS value"),
     "meta is a view"),
    ("probes", "CREATE VIRTUAL TABLE probes USING fts5(seq, measured_um, model_um, accepted, "
     "reason)", "probes is a virtual table"),
])
def test_a_view_or_virtual_table_is_refused_at_once(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], table: str, replacement: str,
        what: str) -> None:
    db = _recorder(tmp_path / "samples.sqlite")
    _sql(db, f"DROP TABLE {table}", replacement)
    model = tmp_path / "m.toml"
    model.write_text(_MODEL)
    # the recursive view never ends: the test finishing at all says it was not run
    for argv in (["refine", str(model), str(db), "-o", str(tmp_path / "o.toml")],
                 ["export", str(db)]):
        assert main(argv) == EX_DATAERR
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and f"({what}, not a table" in err, err
    assert not (tmp_path / "o.toml").exists()


class _Ticking(FakeClock):
    """A clock one second further on at every look: SQLite's progress handler's."""

    def __call__(self) -> float:
        return self.tick()


def test_a_statement_past_its_deadline_is_stopped(tmp_path: Path) -> None:
    db = _recorder(tmp_path / "samples.sqlite", 3000, probe_every=1)
    with RecorderReader(db, clock=_Ticking(), query_s=5.0) as reader:
        with pytest.raises(RecorderError, match=r"cannot read its probes: a read stopped "
                                                r"after 5 s \(one read of a recorder"):
            reader.probes()
        with pytest.raises(RecorderError, match="cannot read: a read stopped after 5 s"):
            reader.read()
    # the same file on the monotonic clock is read whole
    with RecorderReader(db) as reader:
        assert reader.probes()["seq"].size == 3000
        assert reader.read()["seq"].size == 3000


def test_refine_stopped_by_the_deadline_is_one_line_and_65(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    db = _recorder(tmp_path / "samples.sqlite", 3000, probe_every=1)
    model = tmp_path / "m.toml"
    model.write_text(_MODEL)
    monkeypatch.setattr(store_reader, "QUERY_S", -1.0)  # every deadline already past
    assert main(["refine", str(model), str(db), "-o", str(tmp_path / "o.toml")]) == EX_DATAERR
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "a read stopped after -1 s" in err, err


def test_the_field_bound_is_the_csv_readers() -> None:
    assert MAX_FIELD_CHARS == csv.field_size_limit() == 128 * 1024


@pytest.fixture
def built(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """The longest text of every batch of rows the reader built columns from."""
    longest: list[int] = []
    build = store_reader._build

    def measuring(rows: list[Any], *args: Any) -> Any:
        longest.append(max((len(v) for r in rows for v in r if isinstance(v, str | bytes)),
                           default=0))
        return build(rows, *args)

    monkeypatch.setattr(store_reader, "_build", measuring)
    return longest


@pytest.mark.parametrize(("column", "value"), [
    ("state", "x" * (MAX_FIELD_CHARS + 1)),
    ("channels", json.dumps({"bearing": 20.0, "note": "x" * MAX_FIELD_CHARS})),
    ("contributions", json.dumps({"spindle": 1.0, "x" * MAX_FIELD_CHARS: 2.0})),
    ("offset_um", "1" * MAX_FIELD_CHARS + "x"),  # a text where a number belongs
    ("wall_s", b"\x00" * (MAX_FIELD_CHARS + 1)),
])
def test_a_field_past_the_bound_is_refused_by_row_and_column(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], built: list[int], column: str,
        value: str | bytes) -> None:
    db = _recorder(tmp_path / "samples.sqlite", 30)
    _sql(db, f"UPDATE samples SET {column} = ? WHERE seq = 17", params=(value,))
    assert main(["export", str(db), "-o", str(tmp_path / "out.csv")]) == EX_DATAERR
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert f"seq 17, column {column}: a field longer than 128 KiB" in err, err
    assert max(built, default=0) <= MAX_FIELD_CHARS  # the cell never reached Python
    assert not (tmp_path / "out.csv").exists()


def test_a_field_at_the_bound_is_read(tmp_path: Path) -> None:
    db = _recorder(tmp_path / "samples.sqlite", 10)
    _sql(db, "UPDATE samples SET state = ? WHERE seq = 3", params=("y" * MAX_FIELD_CHARS,))
    with RecorderReader(db) as reader:
        cols = reader.read()
    assert cols["state"][cols["seq"] == 3].tolist() == ["y" * MAX_FIELD_CHARS]


def test_a_long_meta_or_probe_field_is_refused(tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    model = tmp_path / "m.toml"
    model.write_text(_MODEL)
    db = _recorder(tmp_path / "probes.sqlite")
    _sql(db, "UPDATE probes SET reason = ? WHERE seq = 9",  # the recorder counts from 1
         params=("z" * (MAX_FIELD_CHARS + 1),))
    assert main(["refine", str(model), str(db), "-o", str(tmp_path / "o.toml")]) == EX_DATAERR
    assert "probe seq 9, column reason: a field longer than 128 KiB" in capsys.readouterr().err
    db = _recorder(tmp_path / "meta.sqlite")
    _sql(db, "UPDATE meta SET value = ? WHERE key = 'channels'",
         params=(json.dumps(["b" * MAX_FIELD_CHARS]),))
    assert main(["export", str(db)]) == EX_DATAERR
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "meta 'channels' is 131076 characters long" in err, err
