"""The recorder keeps each ``[output.axes]`` axis's part of a cycle in its own
table (``axes``: one row per sample and axis), read back by
`RecorderReader.axes`, purged with its sample; the samples, the record readers
and ``compd export`` are as without axes."""

from __future__ import annotations

import dataclasses
import math
import sqlite3
from pathlib import Path

import numpy as np

from compd.cli import main
from compd.core.cycle import Cycle, Outcome
from compd.core.plan import Row
from compd.offline.records import read_record
from compd.runtime.recorder import Recorder
from compd.store.reader import RecorderReader
from compd.store.schema import AXIS_COLUMNS
from compd.testing import FakeClock
from tests.compd.core.cycle_helpers import sp2
from tests.compd.core.test_cycle_axes import axis_params, inputs
from tests.compd.core.test_cycle_axes_position import at, positional

T0 = 1_790_000_000.0


def _rows(n: int, *, nut_lost: bool = True) -> list[Row]:
    """`n` cycles of an X axis: a refused slope write at 10, the nut invalid at 20..24
    (`nut_lost`)."""
    cycle, clock = Cycle(axis_params(slope_limit_um_m=50.0), sp2()), FakeClock(period_s=1.0)
    rows = []
    for k in range(n):
        t = clock.tick()
        nut = math.nan if nut_lost and 20 <= k < 25 else 25.0
        # stamped with the wall clock, as the shell stamps them
        cycle.plan(t, inputs(T0 + t, nut=nut), wall_s=T0 + t)
        rows.append(cycle.commit(Outcome.failed("x_comp_slope") if k == 10 else Outcome()))
    return rows


def test_each_axis_is_recorded_and_read_back(tmp_path: Path) -> None:
    path, rows = tmp_path / "samples.sqlite", _rows(30)
    with Recorder(path, commit_every=4) as rec:
        for row in rows:
            rec.record(row.record)
    with RecorderReader(path) as reader:
        axes = reader.axes()
        samples = reader.read()
    assert list(axes) == ["seq", "mono_s", *AXIS_COLUMNS]
    assert list(axes["seq"]) == list(samples["seq"]) and set(axes["axis"]) == {"x"}
    for k, row in enumerate(rows):
        x = row.axes["x"]
        assert axes["state"][k] == str(x.state) and axes["cause"][k] == str(x.cause)
        assert axes["in_force"][k] == x.in_force
        assert axes["value_um"][k] == x.value.stage
        assert axes["slope_um_m"][k] == x.slope.stage
        confirmed = x.slope.confirmed
        assert (math.isnan(axes["slope_confirmed_um_m"][k]) if confirmed is None
                else axes["slope_confirmed_um_m"][k] == confirmed)
        model = x.value.model
        assert (math.isnan(axes["value_model_um"][k]) if model is None
                else axes["value_model_um"][k] == model)
    # the refused write and the invalid nut show in the record
    assert not axes["in_force"][10] and axes["in_force"][15]
    assert axes["cause"][22] == "inputs_invalid" and np.isnan(axes["value_model_um"][22])
    # the samples see the channels only, as without axes
    assert "x_comp_value" not in samples and "value_um" not in samples


def test_export_round_trips_and_retention_purges_the_axes(tmp_path: Path) -> None:
    path, rows = tmp_path / "samples.sqlite", _rows(30, nut_lost=False)
    with Recorder(path, commit_every=1, keep_rows=10, purge_every_commits=1) as rec:
        for row in rows:
            rec.record(row.record)
    with sqlite3.connect(path) as conn:
        kept = conn.execute("SELECT MIN(seq), COUNT(*) FROM samples").fetchone()
        ax = conn.execute("SELECT MIN(seq), COUNT(*) FROM axes").fetchone()
    conn.close()
    assert ax == kept  # one axis: one row per sample kept, none of the purged ones
    out = tmp_path / "run.csv"
    assert main(["export", str(path), "-o", str(out)]) == 0
    from_db, from_csv = read_record(path), read_record(out)
    # the record readers see the channels only, as without axes
    assert set(from_db.columns) == {"bearing", "ambient", "spindle_rpm", "nut", "offset_um",
                                    "model_um"}
    assert sorted(from_csv.columns) == sorted(from_db.columns)
    for name, col in from_db.columns.items():
        np.testing.assert_array_equal(from_csv.columns[name], col, err_msg=name)


def test_a_file_of_an_older_compd_has_no_axes(tmp_path: Path) -> None:
    path = tmp_path / "old.sqlite"
    with Recorder(path, commit_every=1) as rec:
        rec.record(dataclasses.replace(_rows(1)[0].record, axes={}))
    with sqlite3.connect(path) as conn:
        conn.execute("DROP TABLE axes")
    conn.close()
    with RecorderReader(path) as reader:
        assert len(reader.axes()["seq"]) == 0
    with Recorder(path, commit_every=1) as rec:  # upgraded on open: the table is back
        rec.record(_rows(1)[0].record)
    with RecorderReader(path) as reader:
        assert list(reader.axes()["axis"]) == ["x"]


def _positional_rows(n: int) -> list[Row]:
    """`n` cycles of an X axis written as one offset at its read position, the axis
    moving 100 mm a cycle."""
    cycle, clock = Cycle(positional(), sp2()), FakeClock(period_s=1.0)
    rows = []
    for k in range(n):
        t = clock.tick()
        cycle.plan(t, at(t, 100.0 + 100.0 * k), wall_s=t)  # `at` stamps on wall 0
        rows.append(cycle.commit())
    return rows


def test_an_axis_at_its_position_records_the_position_and_the_offset(tmp_path: Path) -> None:
    path, rows = tmp_path / "samples.sqlite", _positional_rows(5)
    with Recorder(path, commit_every=2) as rec:
        for row in rows:
            rec.record(row.record)
    with RecorderReader(path) as reader:
        axes = reader.axes()
    for k, row in enumerate(rows):
        x = row.axes["x"]
        assert x.position_mm == 100.0 + 100.0 * k and x.offset_um is not None, k
        assert axes["position_mm"][k] == x.position_mm
        assert axes["offset_um"][k] == x.offset_um
    # the slope's part moves with the axis: the offsets differ from cycle to cycle
    assert len(set(axes["offset_um"].tolist())) == len(rows)
    # an axis written as parameters has no position
    plain = _rows(1)
    with Recorder(tmp_path / "plain.sqlite", commit_every=1) as rec:
        rec.record(plain[0].record)
    with RecorderReader(tmp_path / "plain.sqlite") as reader:
        got = reader.axes()
    assert np.isnan(got["position_mm"][0]) and np.isnan(got["offset_um"][0])


def test_a_file_of_an_older_compd_gets_the_position_columns(tmp_path: Path) -> None:
    path = tmp_path / "old.sqlite"
    with Recorder(path, commit_every=1) as rec:
        rec.record(_rows(1)[0].record)
    with sqlite3.connect(path) as conn:  # the axes table as an older compd made it
        conn.execute("ALTER TABLE axes DROP COLUMN position_mm")
        conn.execute("ALTER TABLE axes DROP COLUMN offset_um")
    conn.close()
    with RecorderReader(path) as reader:  # read only: the columns missing read as NaN
        old = reader.axes()
    assert list(old["axis"]) == ["x"] and np.isnan(old["position_mm"][0])
    with Recorder(path, commit_every=1) as rec:  # upgraded on open: the columns are back
        rec.record(_positional_rows(1)[0].record)
    with RecorderReader(path) as reader:
        axes = reader.axes()
    assert np.isnan(axes["position_mm"][0]) and axes["position_mm"][1] == 100.0
    assert axes["offset_um"][1] == _positional_rows(1)[0].axes["x"].offset_um
