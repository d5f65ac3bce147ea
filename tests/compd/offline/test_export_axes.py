"""`compd export` carries each ``[output.axes]`` axis's row beside its sample, as
``<axis>.<column>`` columns joined on ``seq`` and streamed a batch at a time, and
what it writes `fit`, `replay` and `refine` still read (the axes' columns are not
channels, as the recorder database reads them)."""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import math
import sqlite3
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from compd.cli import main
from compd.core.record import RecordRow
from compd.offline.export import Export, write_csv
from compd.offline.records import read_csv_columns, read_record
from compd.runtime.recorder import Recorder
from compd.store.axis_columns import EXPORT_AXIS_COLUMNS
from compd.store.reader import RecorderReader
from compd.store.schema import AXIS_COLUMNS
from compd.sysexits import EX_DATAERR
from tests.compd.offline.test_export_roundtrip import PERIOD_S, TIME_SCALE, _plant
from tests.compd.runtime.test_recorder_axes import _positional_rows, _rows

T0 = 1_795_000_000.0
#: the header of an export of `_samples` without axes (as before axes were exported)
BASE_HEADER = ["time", "wall_s", "mono_s", "seq", "cycle", "state", "valid", "offset_um",
               "model_um", "bearing", "valid.bearing", "contribution.spindle"]


def _samples(n: int) -> list[RecordRow]:
    return [RecordRow(seq=k, mono_s=10.0 * k, wall_s=T0 + k, offset_um=0.1 * k,
                      model_um=0.5 * k, state="running", valid=True,
                      channels={"bearing": 20.0 + 0.01 * k}, contributions={"spindle": 0.2 * k})
            for k in range(n)]


def _with_axes(n: int) -> list[RecordRow]:
    """`n` samples; X (a line written as parameters: a refused write at 10, the nut
    invalid at 20..24) on every sample but 5 and 6, Z (an offset at its position) on
    the odd ones only."""
    xs = [r.record.axes["x"] for r in _rows(max(n, 30))]
    zs = [r.record.axes["x"]._replace(axis="z") for r in _positional_rows(n)]
    out = []
    for k, row in enumerate(_samples(n)):
        axes = {} if k in (5, 6) else {"x": xs[k]}
        if k % 2:
            axes["z"] = zs[k]
        out.append(dataclasses.replace(row, axes=axes))
    return out


def _record(path: Path, rows: list[RecordRow]) -> Path:
    with Recorder(path, commit_every=7) as rec:
        for row in rows:
            rec.record(row)
    return path


def _csv(db: Path, **kwargs: Any) -> str:
    out = io.StringIO()
    with Export(db, **kwargs) as export:
        write_csv(export, out)
    return out.getvalue()


def _cell(value: Any) -> str:
    """A value of `RecorderReader.axes` as `compd export` writes its cell."""
    if isinstance(value, bool | np.bool_):
        return "1" if value else "0"
    if isinstance(value, float | np.floating):
        return repr(float(value)) if math.isfinite(value) else ""
    return str(value)


def test_the_header_names_each_axis_column_after_the_samples(tmp_path: Path) -> None:
    db = _record(tmp_path / "samples.sqlite", _with_axes(12))
    header = _csv(db).splitlines()[0].split(",")
    assert header == [*BASE_HEADER, *(f"{a}.{c}" for a in ("x", "z") for c in AXIS_COLUMNS[1:])]
    assert "x.value_um" in header and "z.position_mm" in header and "x.axis" not in header


def test_a_recorder_without_axes_exports_as_before(tmp_path: Path) -> None:
    db = _record(tmp_path / "samples.sqlite", _samples(12))
    rows = list(csv.reader(io.StringIO(_csv(db))))
    assert rows[0] == BASE_HEADER and len(rows) == 13
    with sqlite3.connect(db) as conn:  # a file of a compd from before the axes table
        conn.execute("DROP TABLE axes")
    conn.close()
    assert list(csv.reader(io.StringIO(_csv(db)))) == rows


def test_each_axis_cell_is_the_recorders_axis_row(tmp_path: Path) -> None:
    db = _record(tmp_path / "samples.sqlite", _with_axes(30))
    rows = list(csv.DictReader(io.StringIO(_csv(db))))
    with RecorderReader(db) as reader:
        axes = reader.axes()
    seen = {"x": 0, "z": 0}
    for i in range(len(axes["seq"])):
        axis = str(axes["axis"][i])
        row = next(r for r in rows if int(r["seq"]) == axes["seq"][i])
        for name in EXPORT_AXIS_COLUMNS:
            assert row[f"{axis}.{name}"] == _cell(axes[name][i]), (axis, name, i)
        seen[axis] += 1
    assert seen == {"x": 28, "z": 15}
    # a sample without an axis's row: every cell of that axis empty
    for r in rows:
        k = int(r["cycle"])
        assert (r["x.state"] == "") == (k in (5, 6)) and (r["z.state"] == "") == (k % 2 == 0)
        if k in (5, 6):
            assert all(r[f"x.{c}"] == "" for c in EXPORT_AXIS_COLUMNS)
    # what the rows hold shows: a refused write, the nut invalid, a position read
    assert rows[10]["x.in_force"] == "0" and rows[15]["x.in_force"] == "1"
    assert rows[22]["x.cause"] == "inputs_invalid" and rows[22]["x.value_model_um"] == ""
    assert float(rows[3]["z.position_mm"]) == 400.0 and rows[3]["x.position_mm"] == ""


@pytest.mark.parametrize("batch_rows", [1, 2, 5, 6, 7])
def test_a_batch_boundary_inside_the_rows_changes_nothing(tmp_path: Path,
                                                         batch_rows: int) -> None:
    """Boundaries at every row, beside and inside the samples without an X row (5, 6)."""
    db = _record(tmp_path / "samples.sqlite", _with_axes(20))
    whole = _csv(db)
    assert _csv(db, batch_rows=batch_rows) == whole
    since, until = T0 + 3.0, T0 + 14.0
    cut = _csv(db, since=since, until=until, batch_rows=batch_rows)
    assert cut == _csv(db, since=since, until=until)
    assert cut.splitlines()[1:] == whole.splitlines()[4:15]


def test_a_window_without_an_axis_has_no_columns_for_it(tmp_path: Path) -> None:
    rows = _with_axes(12)
    rows = [dataclasses.replace(r, axes={}) if k >= 6 else r for k, r in enumerate(rows)]
    db = _record(tmp_path / "samples.sqlite", rows)
    assert _csv(db, since=T0 + 6.0).splitlines()[0].split(",") == BASE_HEADER
    assert "x.state" in _csv(db, until=T0 + 6.0).splitlines()[0]


def test_parquet_types_and_nulls(tmp_path: Path) -> None:
    db = _record(tmp_path / "samples.sqlite", _with_axes(12))
    out = tmp_path / "day.parquet"
    assert main(["export", str(db), "-o", str(out)]) == 0
    table = pq.read_table(out)
    assert table.schema.field("x.state").type == pa.string()
    assert table.schema.field("x.in_force").type == pa.bool_()
    assert table.schema.field("z.position_mm").type == pa.float64()
    got = table.to_pydict()
    assert got["x.state"][5] is None and got["x.in_force"][5] is None
    assert got["x.in_force"][4] is True and got["z.position_mm"][0] is None
    assert got["z.position_mm"][3] == 400.0 and got["x.state"][0] == "ok"
    with RecorderReader(db) as reader:
        axes = reader.axes()
    x = axes["axis"] == "x"
    assert [v for v in got["x.value_um"] if v is not None] == axes["value_um"][x].tolist()


def _plant_with_axes(path: Path, n: int) -> Path:
    """The plant of the export round-trip test, an X axis's row on each sample but
    every tenth (`_rows`'s, reused), a Z axis's on the first half."""
    cols, xs = _plant(n), [r.record.axes["x"] for r in _rows(30)]
    z = xs[0]._replace(axis="z")
    with Recorder(path, commit_every=100) as rec:
        for k in range(n):
            axes = {} if k % 10 == 9 else {"x": xs[k % 30]}
            if k < n // 2:
                axes["z"] = z
            rec.record(RecordRow(
                seq=k + 1, mono_s=1000.0 + PERIOD_S * k, wall_s=T0 + PERIOD_S * k / TIME_SCALE,
                offset_um=0.1 * k, model_um=0.05 * k, state="running", valid=True,
                channels={name: float(c[k]) for name, c in cols.items()},
                contributions={"bearing": 0.01 * k}, axes=axes))
    return path


def test_fit_replay_and_refine_take_an_export_with_axes(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    db = _plant_with_axes(tmp_path / "samples.sqlite", 1440)
    export = tmp_path / "run.csv"
    assert main(["export", str(db), "-o", str(export)]) == 0
    assert "x.state" in export.read_text(encoding="utf-8").splitlines()[0]
    # the axes' columns are not held: 1440 rows × 28 columns of nothing
    header, _, data = read_csv_columns(export, "record")
    assert data.shape[0] == len(header) and not any(h.startswith(("x.", "z.")) for h in header)
    from_db, from_csv = read_record(db), read_record(export)
    assert sorted(from_csv.columns) == sorted(from_db.columns)
    for name, col in from_db.columns.items():
        np.testing.assert_array_equal(from_csv.columns[name], col, err_msg=name)
    capsys.readouterr()
    model = tmp_path / "m.toml"
    assert main(["fit", str(export), "--column", "dz_um", "--term", "bearing",
                 "--term", "ambient", "-o", str(model)]) == 0, capsys.readouterr().err
    capsys.readouterr()
    figures = []
    for record in (db, export):
        assert main(["replay", str(model), str(record), "--column", "dz_um", "--json"]) == 0
        figures.append(json.loads(capsys.readouterr().out.splitlines()[-1]))
    assert figures[0]["fit_percent"] == figures[1]["fit_percent"] > 90.0
    # an axis's column is no channel: named as the displacement, it is refused in one line
    assert main(["replay", str(model), str(export), "--column", "x.value_um"]) == EX_DATAERR
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "'x.value_um'" in err
    # refine takes probes; an export has none, axes or not, and says so in one line
    assert main(["refine", str(model), str(export), "-o", str(tmp_path / "r.toml")]) == 65
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "measured_um" in err and "not a number" not in err


def _corrupt(tmp_path: Path, sql: str) -> Path:
    db = _record(tmp_path / "samples.sqlite", _with_axes(12))
    with sqlite3.connect(db) as conn:
        conn.execute(sql)
    conn.close()
    return db


@pytest.mark.parametrize(("sql", "said"), [
    ("UPDATE axes SET axis = 'w' WHERE seq = 3", "'w', not an axis"),
    ("UPDATE axes SET axis = 'x,\n' || hex(randomblob(500)) WHERE seq = 4", "not an axis"),
    ("UPDATE axes SET value_um = 'twelve' WHERE seq = 8", "corrupt axis rows near seq"),
    ("UPDATE axes SET value_um = zeroblob(200000) WHERE seq = 8", "axis seq 8, column "
                                                                  "value_um: a field longer"),
])
def test_a_corrupt_axis_row_ends_in_one_line(tmp_path: Path, sql: str, said: str,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    db = _corrupt(tmp_path, sql)
    out = tmp_path / "out.csv"
    assert main(["export", str(db), "-o", str(out)]) == EX_DATAERR
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and said in err and "samples.sqlite" in err, err
    assert len(err) < 400 and not out.exists()


def test_a_channel_named_as_an_axis_column_is_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rows = [dataclasses.replace(r, channels={**r.channels, "x.state": 1.0})
            for r in _with_axes(12)]
    db = _record(tmp_path / "samples.sqlite", rows)
    assert main(["export", str(db)]) == EX_DATAERR
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "'x.state'" in err


def test_an_over_long_field_of_an_axis_row_is_named_by_its_sample(tmp_path: Path) -> None:
    """`RecorderReader.axes` names the row by its sample's ``seq``, not the rowid of
    the axis row (with two axes they part from the third sample on)."""
    db = _corrupt(tmp_path, "UPDATE axes SET cause = hex(zeroblob(200000)) WHERE seq = 10"
                            " AND axis = 'z'")
    with RecorderReader(db) as reader, pytest.raises(Exception, match=r"axis seq 10, column cause"):
        reader.axes()


def test_an_axes_table_without_its_key_is_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Each batch's axis rows are a key range; without the key every batch would
    scan the whole table (a month's rows, once per 8192 samples)."""
    db = _record(tmp_path / "samples.sqlite", _with_axes(12))
    with sqlite3.connect(db) as conn:
        conn.execute("ALTER TABLE axes RENAME TO keyed")
        conn.execute("CREATE TABLE axes AS SELECT * FROM keyed")
        conn.execute("DROP TABLE keyed")
    conn.close()
    assert main(["export", str(db)]) == EX_DATAERR
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no key on seq" in err
