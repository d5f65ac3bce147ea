"""The one recorder reader (`compd.store.reader`): rows streamed in bounded
batches and cut to a wall-clock window, what happens to rows written or purged
while it reads, no size cap, and every hostile file refused with one error."""

from __future__ import annotations

import contextlib
import csv
import io
import os
import sqlite3
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from compd.cli import main
from compd.infiles import InputError
from compd.offline.export import Export, write_csv
from compd.offline.records import RecordError, read_record
from compd.runtime.recorder import Recorder, RecordRow
from compd.store import reader as store_reader
from compd.store.reader import RecorderReader, read_samples
from compd.store.schema import RecorderError
from compd.sysexits import EX_DATAERR, EX_NOINPUT
from tests.compd.store.recorder_layouts import write_previous

T0 = 1_795_000_000.0


def _row(k: int, wall_s: float | None = None) -> RecordRow:
    return RecordRow(seq=k, mono_s=float(k), wall_s=T0 + k if wall_s is None else wall_s,
                     offset_um=0.1 * k, model_um=0.1 * k, state="ok", valid=True,
                     channels={"bearing": 20.0 + 0.01 * k, "dz_um": 0.5 * k},
                     contributions={"spindle": 0.1 * k})


def _db(path: Path, n: int) -> Path:
    with Recorder(path, commit_every=25) as rec:
        for k in range(n):
            rec.record(_row(k))
    return path


@pytest.fixture
def held(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """The number of rows each batch the reader built held at once."""
    sizes: list[int] = []
    build = store_reader._build

    def counting(rows: list[Any], *args: Any) -> Any:
        sizes.append(len(rows))
        return build(rows, *args)

    monkeypatch.setattr(store_reader, "_build", counting)
    return sizes


def test_rows_come_in_batches_of_at_most_batch_rows(tmp_path: Path, held: list[int]) -> None:
    db = _db(tmp_path / "rec.sqlite", 100)
    with RecorderReader(db, batch_rows=7) as reader:
        batches = list(reader.batches())
    assert [len(b["seq"]) for b in batches] == [7] * 14 + [2]
    assert max(held) == 7 and sum(held) == 100  # never more than 7 rows built at once
    joined = np.concatenate([b["seq"] for b in batches])
    assert joined.tolist() == list(range(1, 101))
    whole = read_samples(db)
    for name, col in whole.items():
        np.testing.assert_array_equal(np.concatenate([b[name] for b in batches]), col)


def test_a_window_is_read_from_its_first_to_its_last_row(tmp_path: Path) -> None:
    """Rows stamped in [since, until); a clock set back mid-record stamps rows out
    of order, and those inside the window are read, in seq order."""
    path = tmp_path / "rec.sqlite"
    walls = [T0 + k for k in range(20)] + [T0 + 5.5, T0 + 30.0, T0 + 6.5]
    with Recorder(path, commit_every=5) as rec:
        for k, wall in enumerate(walls):
            rec.record(_row(k, wall))
    with RecorderReader(path, batch_rows=3) as reader:
        cols = reader.read(T0 + 5.0, T0 + 8.0)
        assert reader.read(T0 + 100.0).keys() == cols.keys()  # empty, same columns
        assert reader.read(T0 + 100.0)["seq"].size == 0
    assert cols["wall_s"].tolist() == [T0 + 5, T0 + 6, T0 + 7, T0 + 5.5, T0 + 6.5]
    assert cols["seq"].tolist() == [6, 7, 8, 21, 23]


def test_rows_purged_or_written_while_reading(tmp_path: Path) -> None:
    """The rows up to the newest committed when the iteration starts; a row that
    retention deletes between two batches is not read, and nothing fails."""
    db = _db(tmp_path / "rec.sqlite", 30)
    with RecorderReader(db, batch_rows=10) as reader:
        it: Iterator[dict[str, Any]] = reader.batches()
        first = next(it)
        with contextlib.closing(sqlite3.connect(db)) as conn:
            conn.execute("DELETE FROM samples WHERE seq BETWEEN 11 AND 15")
            conn.commit()
        with Recorder(db, commit_every=1) as rec:
            rec.record(_row(99))
        rest = [b["seq"].tolist() for b in it]
    assert first["seq"].tolist() == list(range(1, 11))
    assert rest == [list(range(16, 26)), list(range(26, 31))]


def test_export_streams_the_same_table_whatever_the_batch(tmp_path: Path,
                                                          held: list[int]) -> None:
    db = _db(tmp_path / "rec.sqlite", 50)
    outs = []
    for batch_rows in (4, 1000):
        out = io.StringIO()
        with Export(db, T0 + 3, T0 + 45, batch_rows=batch_rows) as export:
            write_csv(export, out)
        assert export.rows == 42
        outs.append(out.getvalue())
    assert outs[0] == outs[1]
    assert max(held[:11]) == 4  # the first export never built more than 4 rows at once
    rows = list(csv.DictReader(io.StringIO(outs[0])))
    assert rows[0]["seq"] == "4" and rows[-1]["seq"] == "45"
    assert rows[0]["contribution.spindle"] == "0.30000000000000004"


def test_a_recorder_file_past_the_old_512_mib_cap_is_read(tmp_path: Path) -> None:
    """The size of the file is no reason to refuse it (it is streamed): a
    recorder padded to 600 MiB (sparse: no disk used) reads and replays."""
    db = _db(tmp_path / "big.db", 40)
    with contextlib.closing(sqlite3.connect(db)) as conn:
        conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    with db.open("r+b") as f:
        f.truncate(600 << 20)
    assert read_samples(db)["seq"].size == 40
    assert len(read_record(db)) == 40


def test_the_previous_layout_replays_and_exports(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    db = tmp_path / "previous.db"
    write_previous(db, [_row(k) for k in range(30)])
    rec = read_record(db)
    np.testing.assert_allclose(rec.column("bearing"), [20.0 + 0.01 * k for k in range(30)])
    assert main(["export", str(db)]) == 0
    rows = list(csv.DictReader(io.StringIO(capsys.readouterr().out)))
    assert len(rows) == 30 and rows[2]["contribution.spindle"] == "0.2"
    assert rows[2]["valid.bearing"] == "1"


def _not_a_recorder(path: Path, kind: str) -> None:
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "directory":
        path.mkdir()
    elif kind == "text":
        path.write_text("seq,wall_s\n1,2\n")
    elif kind == "empty":
        path.write_bytes(b"")
    elif kind == "truncated":
        _db(path, 30)
        with contextlib.closing(sqlite3.connect(path)) as conn:
            conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")
        data = path.read_bytes()
        path.write_bytes(data[:100] + b"\xff" * (len(data) - 100))
    else:
        with contextlib.closing(sqlite3.connect(path)) as conn:
            if kind == "other_sqlite":
                conn.execute("CREATE TABLE things (a, b)")
            elif kind == "lacks_columns":
                conn.execute("CREATE TABLE samples (seq INTEGER PRIMARY KEY, wall_s REAL)")
            elif kind == "samples_view":
                conn.execute("CREATE TABLE t (seq, cycle, mono_s, wall_s, offset_um, model_um,"
                             " state, valid, channels, validity, contributions)")
                conn.execute("CREATE VIEW samples AS SELECT * FROM t")
                conn.execute("CREATE TABLE meta (key, value)")
                conn.execute("INSERT INTO t VALUES (1, 1, 1.0, 1.0, 0, 0, 0, 1, '{}', '{}', '{}')")
            conn.commit()
        if kind in ("bad_meta", "bad_row"):
            path.unlink()
            _db(path, 5)
            with contextlib.closing(sqlite3.connect(path)) as conn:
                if kind == "bad_meta":
                    conn.execute("UPDATE meta SET value = '{\"a\": 1}' WHERE key = 'channels'")
                else:
                    conn.execute("UPDATE samples SET channels = '[1, 2]' WHERE seq = 4")
                conn.commit()


@pytest.mark.parametrize(("kind", "error", "code"), [
    ("fifo", InputError, EX_NOINPUT), ("directory", InputError, EX_NOINPUT),
    ("text", RecorderError, EX_DATAERR), ("empty", RecorderError, EX_DATAERR),
    ("truncated", RecorderError, EX_DATAERR), ("other_sqlite", RecorderError, EX_DATAERR),
    ("lacks_columns", RecorderError, EX_DATAERR), ("samples_view", RecorderError, EX_DATAERR),
    ("bad_meta", RecorderError, EX_DATAERR), ("bad_row", RecorderError, EX_DATAERR)])
def test_what_is_not_a_recorder_ends_in_one_line(kind: str, error: type[Exception], code: int,
                                                 tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "samples.db"
    _not_a_recorder(path, kind)
    with pytest.raises(error):
        read_samples(path)
    if error is RecorderError:
        with pytest.raises(RecordError, match=r"samples\.db"):
            read_record(path)
    for argv in (["export", str(path)], ["replay", "sp2", str(path), "--column", "dz_um"],
                 ["fit", str(path), "--column", "dz_um", "--term", "bearing",
                  "-o", str(path.parent / "m.toml")]):
        assert main(argv) == code, argv
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "Traceback" not in err, err


@pytest.mark.parametrize("miscount", [-5, 0, 5])
def test_read_fills_whole_columns_whatever_changed_since_the_count(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, miscount: int) -> None:
    """`read` sizes its columns by a count, then fills them: rows retention deletes
    after the count (fewer) or rows committed inside the span after it (more)
    still give exactly the rows read, in order."""
    db = _db(tmp_path / "rec.sqlite", 40)
    count = RecorderReader._count
    monkeypatch.setattr(RecorderReader, "_count",
                        lambda self, *a: count(self, *a) + miscount)
    with RecorderReader(db, batch_rows=6) as reader:
        cols = reader.read()
        record = reader.read(detail=False)
    assert cols["seq"].tolist() == list(range(1, 41))
    assert cols["state"].tolist() == ["ok"] * 40
    assert record["bearing"].tolist() == cols["bearing"].tolist()
    assert sorted(record) == ["bearing", "cycle", "dz_um", "model_um", "mono_s", "offset_um"]


def test_a_corrupt_row_is_named_by_its_seq(tmp_path: Path) -> None:
    path = tmp_path / "samples.db"
    _not_a_recorder(path, "bad_row")
    with pytest.raises(RecorderError, match=r"corrupt row, seq 4 \(TypeError"):
        read_samples(path)
