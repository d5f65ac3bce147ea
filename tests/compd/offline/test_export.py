"""`compd export` (the recorder as CSV or Parquet, cut to a wall-clock
window) and `compd replay` on the daemon's own recorder written at a
`time_scale` other than 1 (refused by the CSV jitter rule before)."""

from __future__ import annotations

import asyncio
import csv
import io
import json
import random
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from compd.cli import main
from compd.config.loader import load_config
from compd.offline.records import RecordError, read_record
from compd.runtime.daemon import Daemon
from compd.runtime.recorder import Recorder, RecordRow
from compd.runtime.sdnotify import Notifier
from compd.sysexits import EX_DATAERR, EX_USAGE
from compd.testing import SteppedClock
from drivers.sim.modbus_server import ModbusSimController
from tests.configs import write_config

T0 = 1_795_000_000.0  # 2026-11-18T11:06:40Z


def _recorder(path: Path, n: int, *, jitter: float = 0.0, cycles: list[int] | None = None,
              period_s: float = 10.0, missing_at: int | None = 3) -> Path:
    rng = random.Random(3)
    with Recorder(path, commit_every=50) as rec:
        for k in range(n):
            cycle = k if cycles is None else cycles[k]
            mono = period_s * cycle + (rng.uniform(-jitter, jitter) * period_s if k else 0.0)
            rec.record(RecordRow(seq=cycle, mono_s=mono, wall_s=T0 + k, offset_um=0.1 * k,
                                 model_um=0.5 * k, state="running", valid=True,
                                 channels={"bearing": 20.0 + 0.01 * k,
                                           "ambient": None if k == missing_at else 21.0},
                                 contributions={"spindle": 0.2 * k}))
    return path


def test_export_csv_to_stdout_cut_to_a_window(tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    db = _recorder(tmp_path / "samples.sqlite", 20)
    assert main(["export", str(db), "--since", "2026-11-18T11:06:45Z",
                 "--until", "2026-11-18T11:06:50+00:00"]) == 0
    rows = list(csv.DictReader(io.StringIO(capsys.readouterr().out)))
    assert [float(r["wall_s"]) for r in rows] == [T0 + k for k in range(5, 10)]
    first = rows[0]
    assert first["time"] == "2026-11-18T11:06:45.000+00:00"
    assert float(first["bearing"]) == pytest.approx(20.05)
    assert first["valid.bearing"] == "1" and first["contribution.spindle"] == "1.0"
    assert list(first)[:4] == ["time", "wall_s", "mono_s", "seq"]


def test_export_marks_a_missing_value_empty(tmp_path: Path) -> None:
    db = _recorder(tmp_path / "samples.sqlite", 6)
    out = tmp_path / "all.csv"
    assert main(["export", str(db), "-o", str(out)]) == 0
    rows = list(csv.DictReader(io.StringIO(out.read_text(encoding="utf-8"))))
    assert len(rows) == 6 and rows[3]["ambient"] == "" and rows[3]["valid.ambient"] == "0"
    assert main(["export", str(db), "-o", str(out)]) != 0  # never replaced without --force


def test_export_parquet_keeps_types_and_nulls(tmp_path: Path) -> None:
    db = _recorder(tmp_path / "samples.sqlite", 12)
    out = tmp_path / "day.parquet"
    assert main(["export", str(db), "-o", str(out), "--since", "2026-11-18T11:06:42"]) == 0
    table = pq.read_table(out).to_pydict()
    assert table["wall_s"] == [T0 + k for k in range(2, 12)]
    assert table["ambient"][1] is None and table["ambient"][0] == 21.0
    assert table["seq"][0] == 3 and table["state"][0] == "running"


@pytest.mark.parametrize("argv", [["--format", "parquet"], ["--since", "yesterday"],
                                  ["--since", "2026-11-19", "--until", "2026-11-18"]])
def test_export_usage_errors(argv: list[str], tmp_path: Path,
                             capsys: pytest.CaptureFixture[str]) -> None:
    db = _recorder(tmp_path / "samples.sqlite", 4)
    try:
        rc = main(["export", str(db), *argv])
    except SystemExit as exc:
        rc = exc.code  # type: ignore[assignment]
    assert rc == EX_USAGE
    assert capsys.readouterr().err.count("\n") == 1


def test_export_refuses_what_is_not_a_recorder(tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    junk = tmp_path / "junk.db"
    junk.write_text("not sqlite")
    assert main(["export", str(junk)]) == EX_DATAERR
    assert "junk.db" in capsys.readouterr().err


def test_a_recorder_at_a_time_scale_is_judged_on_its_cycles(tmp_path: Path) -> None:
    """At time_scale 50 a few ms of event-loop lateness is ±30 % of the period
    in machine time: the cycle numbering says the rows are one per period."""
    rec = read_record(_recorder(tmp_path / "fast.db", 40, jitter=0.3, missing_at=None))
    assert rec.period_s == 10.0 and rec.time_s[-1] == 390.0
    with pytest.raises(RecordError, match="missing"):
        read_record(_recorder(tmp_path / "gap.db", 10, cycles=[*range(5), *range(6, 11)],
                              missing_at=None))
    with pytest.raises(RecordError, match="missed deadline"):
        read_record(_late_db(tmp_path / "late.db"))


def _late_db(path: Path) -> Path:
    with Recorder(path, commit_every=50) as rec:
        for k in range(10):
            mono = 10.0 * (k + 2 if k >= 6 else k)  # an overrun: two deadlines skipped
            rec.record(RecordRow(seq=k, mono_s=mono, wall_s=T0 + k, offset_um=None,
                                 model_um=0.0, state="running", valid=True,
                                 channels={"bearing": 20.0}))
    return path


async def _recorder_at_time_scale(tmp_path: Path, time_scale: float) -> Path:
    """A real daemon against the simulated Modbus controller at `time_scale`,
    the bearing stepped twice; its recorder database. The daemon runs on a
    stepped clock (one period per tick, given once it sleeps), so its deadlines
    and the recorded intervals are exact however busy the machine is."""
    await asyncio.to_thread(tmp_path.mkdir)
    sim = ModbusSimController()
    await sim.start()
    try:
        await sim.publish({"bearing": 20.0, "ambient": 20.0})
        cfg = load_config(write_config(tmp_path, sim.endpoint, time_scale=time_scale,
                                       timeout_s=0.5 / time_scale))
        clock = SteppedClock(period_s=1.0 / time_scale, start_s=1000.0)
        daemon = Daemon(cfg, notifier=Notifier(None), clock=clock, sleep=clock.sleep)
        task = asyncio.create_task(daemon.run())
        await clock.cycle_done(1)  # connected, the first cycle done, asleep
        for target, bearing in ((20, 23.0), (60, 21.5), (100, None)):
            while daemon.loop.cycles < target:
                begun = clock.sleeps
                clock.tick()
                await clock.cycle_done(begun + 1)
            if bearing is not None:
                await sim.publish({"bearing": bearing})
        # the stop with the next period's tick (a stop alone would wake it early, to a
        # last cycle at the same clock reading), then periods until it has stopped
        while not task.done():
            begun = clock.sleeps
            daemon.request_stop()
            clock.tick()
            slept = asyncio.ensure_future(clock.cycle_done(begun + 1))
            await asyncio.wait([task, slept], return_when=asyncio.FIRST_COMPLETED)
            slept.cancel()
            await asyncio.gather(slept, return_exceptions=True)
        assert await task == 0
    finally:
        await sim.stop()
    assert cfg.recorder_path is not None
    return cfg.recorder_path


async def test_replay_reads_the_daemons_recorder_written_at_a_time_scale(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A recorder written at a time scale (2x: the machine's clock runs at twice the
    real one) is a record. The deadlines are the stepped clock's (exact), but a read
    still has a real timeout (at most half the real period): at 50x that was 10 ms,
    which a loaded machine missed in five runs out of five (replay rightly refuses a
    sample with no valid value); at 2x it is 250 ms. A run that still misses one is
    repeated (at most five runs)."""
    for attempt in range(5):
        db = await _recorder_at_time_scale(tmp_path / f"run{attempt}", 2.0)
        rc = await asyncio.to_thread(main, ["replay", "sp2", str(db), "--column",
                                            "model_um", "--json"])
        out, err = capsys.readouterr()
        if rc != 0 and ("missed deadline" in err or "no valid value recorded" in err):
            continue
        break
    assert rc == 0, err
    assert json.loads(out.splitlines()[-1])["fit_percent"] > 99.0
