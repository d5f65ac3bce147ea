"""`compd fit` keeps of a record only the columns it fits (and the speeds it warns
about): the reader stores no other (every cell still checked), a month at 1 s
being 21 MB a column."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from compd.offline.fit_records import read_records
from compd.offline.fit_request import FitRequest


def test_the_records_hold_only_the_columns_the_fit_reads(tmp_path: Path) -> None:
    path = tmp_path / "rec.csv"
    rng = np.random.default_rng(0)
    rows = [f"{k},{1000 * (k // 50)},{20 + 0.01 * k:.3f},{19 + rng.normal():.3f},"
            f"{0.1 * k:.3f},{0.02 * k + rng.normal():.3f}" for k in range(200)]
    path.write_text("time_s,speed_rpm,bearing,table,power_kw,dz_um\n" + "\n".join(rows) + "\n")
    request = FitRequest(data=(str(path),), output="dz_um", term=("bearing",))
    (record,) = read_records([str(path)], request, {"bearing"})
    assert sorted(record.columns) == ["bearing", "dz_um", "speed_rpm"]
    # the reader stored only those (and the time): no block of every column behind them
    block = record.columns["bearing"].base
    assert block is None or block.shape[0] == 4
    assert record.column("dz_um")[199] == float(rows[199].rsplit(",", 1)[1])
    (every,) = read_records([str(path)], request, set())  # --candidates: every column
    assert sorted(every.columns) == ["bearing", "dz_um", "power_kw", "speed_rpm", "table"]
    # a fixed term reads channels of its own
    fixing = dataclasses.replace(request, fixed=("other.toml:table",))
    (fixed,) = read_records([str(path)], fixing, {"bearing"})
    assert sorted(fixed.columns) == sorted(every.columns)


def test_a_column_fit_does_not_read_is_still_checked(tmp_path: Path) -> None:
    import pytest

    from compd.offline.records import RecordError

    path = tmp_path / "rec.csv"
    rows = [f"{k},{20 + 0.01 * k:.3f},{19 + 0.001 * k:.3f},{0.02 * k:.3f}" for k in range(50)]
    rows[30] = "30,20.3,oops,0.6"
    path.write_text("time_s,bearing,table,dz_um\n" + "\n".join(rows) + "\n")
    request = FitRequest(data=(str(path),), output="dz_um", term=("bearing",))
    with pytest.raises(RecordError, match=r"row 32.*table"):
        read_records([str(path)], request, {"bearing"})


def test_the_reader_keeps_what_it_is_asked_and_the_time(tmp_path: Path) -> None:
    from compd.offline.records import columns_named, read_record

    path = tmp_path / "rec.csv"
    rows = [f"{k},{500 * (k // 10)},{20 + 0.01 * k:.3f},{19 + 0.001 * k:.3f},{0.02 * k:.3f}"
            for k in range(50)]
    path.write_text("time_s,spindle_rpm,t01_degC,table,dz_um\n" + "\n".join(rows) + "\n")
    whole = read_record(path)
    kept = read_record(path, columns_named(["dz_um", "t1_degC"], speeds=True))
    kept.require(["dz_um", "t1_degC"])  # the former spelling, filed under the name asked for
    assert sorted(kept.columns) == ["dz_um", "spindle_rpm", "t1_degC"]
    np.testing.assert_array_equal(kept.time_s, whole.time_s)
    np.testing.assert_array_equal(kept.column("t1_degC"), whole.column("t01_degC"))
    assert kept.period_s == whole.period_s and kept.sha256 == whole.sha256
    bare = read_record(path, columns_named(["dz_um"]))
    assert sorted(bare.columns) == ["dz_um"]
