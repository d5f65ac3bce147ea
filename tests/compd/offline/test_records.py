"""Calibration records are checked, never repaired."""

from __future__ import annotations

from pathlib import Path

import pytest

from compd.offline.records import RecordError, check_units, read_csv_record, speed_warnings


def _write(path: Path, rows: list[str], header: str = "time_s,bearing,dz_um") -> Path:
    path.write_text(header + "\n" + "\n".join(rows) + "\n", encoding="utf-8")
    return path


def test_a_good_record_gives_its_period_and_columns(tmp_path: Path) -> None:
    rec = read_csv_record(_write(tmp_path / "r.csv", [f"{10 * k},{20 + k / 10},{k}.5"
                                                     for k in range(5)]))
    assert rec.period_s == 10.0
    assert list(rec.columns) == ["bearing", "dz_um"]
    assert len(rec) == 5
    assert len(rec.sha256) == 64


def test_iso_8601_timestamps(tmp_path: Path) -> None:
    rows = [f"2026-03-01T10:00:{15 * k:02d}Z,20.{k},1.{k}" for k in range(4)]
    rec = read_csv_record(_write(tmp_path / "r.csv", rows, "timestamp,bearing,dz_um"))
    assert rec.period_s == 15.0
    assert rec.time_s.tolist() == [0.0, 15.0, 30.0, 45.0]


@pytest.mark.parametrize(("rows", "needle"), [
    (["0,20,1", "1,20,1", "1,20,1", "2,20,1"], "row 4: duplicated timestamp"),
    (["0,20,1", "1,20,1", "2,20,1", "5,20,1", "6,20,1"], "row 5: gap of 3 s"),
    (["0,20,1", "1,20,1", "2,20,1", "3.3,20,1", "4,20,1"], "non-uniform sampling"),
    (["0,20,1", "1,nan,1", "2,20,1"], "row 3, column 'bearing'"),
    (["0,20,1", "1,,1", "2,20,1"], "empty cell"),
    (["0,20,1", "1,20", "2,20,1"], "row 3: 2 fields"),
])
def test_broken_records_name_the_row(tmp_path: Path, rows: list[str], needle: str) -> None:
    with pytest.raises(RecordError, match=needle):
        read_csv_record(_write(tmp_path / "r.csv", rows))


def test_unit_mistakes_are_refused(tmp_path: Path) -> None:
    mk = read_csv_record(_write(tmp_path / "mk.csv", [f"{k},{20000 + k},{k * 3}"
                                                      for k in range(5)]))
    with pytest.raises(RecordError, match="looks like mK"):
        check_units(mk, ["bearing"], "dz_um")
    mm = read_csv_record(_write(tmp_path / "mm.csv", [f"{k},20,{0.001 * k}"
                                                      for k in range(50)]))
    with pytest.raises(RecordError, match="looks like mm"):
        check_units(mm, ["bearing"], "dz_um")


def test_no_time_column_is_refused(tmp_path: Path) -> None:
    with pytest.raises(RecordError, match="no time column"):
        read_csv_record(_write(tmp_path / "r.csv", ["1,2", "3,4", "5,6"], "a,b"))


def test_constant_speed_heat_up_alone_is_warned_about(tmp_path: Path) -> None:
    rows = [f"{10 * k},9000,{20 + k / 100},{k}" for k in range(200)]
    rec = read_csv_record(_write(tmp_path / "r.csv", rows, "time_s,spindle_rpm,bearing,dz_um"))
    assert any("constant-speed heat-up" in w for w in speed_warnings(rec))
    rows += [f"{10 * k},0,{22 - k / 1000},{k}" for k in range(200, 300)]
    rec = read_csv_record(_write(tmp_path / "r2.csv", rows, "time_s,spindle_rpm,bearing,dz_um"))
    assert speed_warnings(rec) == []


def _recorder_db(path: Path, n: int, *, missing_at: int | None = None,
                 restart_at: int | None = None) -> Path:
    from compd.runtime.recorder import Recorder, RecordRow

    with Recorder(path, commit_every=50) as rec:
        for k in range(n):
            t = 10.0 * (k if restart_at is None or k < restart_at else k - restart_at)
            bearing: float | None = 20.0 + 0.01 * k
            if k == missing_at:
                bearing = None
            rec.record(RecordRow(seq=k, mono_s=t, wall_s=1e9 + 10.0 * k, offset_um=None,
                                 model_um=0.5 * k, state="running", valid=True,
                                 channels={"bearing": bearing, "dz_um": 0.03 * k}))
    return path


def test_a_recorder_database_reads_as_a_record(tmp_path: Path) -> None:
    from compd.offline.records import read_record

    rec = read_record(_recorder_db(tmp_path / "run.db", 30))
    assert rec.period_s == 10.0 and len(rec) == 30
    assert set(rec.columns) == {"bearing", "dz_um", "model_um"}  # offset_um was never written
    assert rec.column("bearing")[3] == pytest.approx(20.03)
    assert len(rec.sha256) == 64


def test_a_recorder_database_with_a_gap_in_a_channel_or_a_restart_is_refused(
        tmp_path: Path) -> None:
    from compd.offline.records import read_record

    with pytest.raises(RecordError, match=r"row 7, column 'bearing': no valid value"):
        read_record(_recorder_db(tmp_path / "gap.db", 20, missing_at=5))
    with pytest.raises(RecordError, match="backwards"):
        read_record(_recorder_db(tmp_path / "restart.sqlite", 20, restart_at=12))
    (tmp_path / "junk.db").write_text("not sqlite")
    with pytest.raises(RecordError, match=r"junk\.db"):
        read_record(tmp_path / "junk.db")
