"""Offline calibration records: CSV header, row count, content."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from drivers.sim.csvlog import RECORD_COLUMNS, write_record
from drivers.sim.offline import record_program, simulate
from drivers.sim.programs import constant, make_program
from tests.record_columns import read_columns as read_record

HEADER = "time_s,spindle_rpm,bearing,motor,column,table,ambient,power_kw,dz_um"


def test_one_hour_at_one_second_has_3601_rows_and_the_header(tmp_path: Path) -> None:
    path = tmp_path / "rec.csv"
    rows = record_program(path, make_program("spectrum", seed=3, hours=1.0), seed=3)
    assert rows == 3601
    lines = path.read_text().splitlines()
    assert lines[0] == HEADER
    assert len(lines) == 3602
    assert not (tmp_path / "rec.csv.part").exists()
    rec = read_record(path)
    assert tuple(rec) == RECORD_COLUMNS
    assert np.array_equal(rec["time_s"], np.arange(3601.0))
    assert rec["spindle_rpm"][0] == 0.0  # row 0: the machine before the program starts
    speeds = rec["spindle_rpm"][1:]
    assert np.all((speeds >= 500.0) & (speeds <= 10_000.0))
    assert np.all(np.abs(rec["bearing"] * 10 - np.round(rec["bearing"] * 10)) < 1e-9)


def test_period_sets_the_row_count_and_the_record_is_deterministic(tmp_path: Path) -> None:
    prog = constant(heat_h=1.0, cool_h=1.0)
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    assert record_program(a, prog, seed=1, period_s=10.0) == 721
    record_program(b, prog, seed=1, period_s=10.0)
    assert a.read_bytes() == b.read_bytes()
    rec = read_record(a)
    assert rec["time_s"][-1] == 7200.0
    heat = rec["dz_um"][rec["time_s"] <= 3600.0]
    assert heat[-1] > heat[0] + 10.0  # the heat-up shows in the measured growth


def test_probe_noise_is_optional_and_about_its_size() -> None:
    prog = make_program("spectrum", seed=0, hours=2.0)
    noisy = simulate(prog, seed=0, probe_noise_um=0.5)
    clean = simulate(prog, seed=0, probe_noise_um=0.0)
    assert np.array_equal(clean["dz_um"], clean["growth_um"])
    assert np.array_equal(noisy["growth_um"], clean["growth_um"])
    assert float(np.std(noisy["dz_um"] - noisy["growth_um"])) == pytest.approx(0.5, rel=0.1)


def test_write_record_refuses_ragged_or_missing_columns(tmp_path: Path) -> None:
    cols = {c: np.zeros(3) for c in RECORD_COLUMNS}
    with pytest.raises(ValueError, match="lacks"):
        write_record(tmp_path / "x.csv", {k: v for k, v in cols.items() if k != "dz_um"})
    cols["dz_um"] = np.zeros(2)
    with pytest.raises(ValueError, match="length"):
        write_record(tmp_path / "x.csv", cols)
