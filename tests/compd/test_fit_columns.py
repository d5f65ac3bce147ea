"""`compd fit` keeps of a record only the columns it fits (and the speeds it warns
about): the rest of the block the reader parsed is freed, a month at 1 s being
21 MB a column."""

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
    assert record.columns["bearing"].base is None  # its own array, not a view of the block
    assert record.column("dz_um")[199] == float(rows[199].rsplit(",", 1)[1])
    (every,) = read_records([str(path)], request, set())  # --candidates: every column
    assert sorted(every.columns) == ["bearing", "dz_um", "power_kw", "speed_rpm", "table"]
    # a fixed term reads channels of its own
    fixing = dataclasses.replace(request, fixed=("other.toml:table",))
    (fixed,) = read_records([str(path)], fixing, {"bearing"})
    assert sorted(fixed.columns) == sorted(every.columns)
