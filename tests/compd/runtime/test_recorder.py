"""The sample recorder: round trip into numpy columns, seq numbering across
restarts, retention, a kill -9 of a writer, and a full disk (a real ENOSPC from
a small tmpfs) that never stops the caller and recovers by itself."""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import random
import signal
import sqlite3
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from compd.errors import CompdError
from compd.infiles import InputError
from compd.runtime.recorder import Recorder, RecorderError, RecordRow, read_samples
from tests.tmpfs import fill, small_tmpfs

ROOT = Path(__file__).resolve().parents[3]


def _row(i: int, **channels: float | None) -> RecordRow:
    chans: dict[str, float | None] = {"t_spindle_c": 20.0 + i, "t_ambient_c": 21.5}
    chans.update(channels)
    return RecordRow(mono_s=float(i), wall_s=1.0e9 + i, offset_um=-0.5 * i, model_um=-0.5 * i,
                     state="ok", valid=True, channels=chans,
                     validity={k: None for k in chans},
                     contributions={"spindle": -0.4 * i, "ambient": -0.1 * i}, seq=i)


def _seqs(path: Path) -> list[int]:
    with contextlib.closing(sqlite3.connect(path)) as conn:
        return [r[0] for r in conn.execute("SELECT seq FROM samples ORDER BY seq")]


def test_wal_mode_and_columns(tmp_path: Path) -> None:
    path = tmp_path / "rec.sqlite"
    rec = Recorder(path, commit_every=4)
    rec.open()
    for i in range(10):
        rec.record(_row(i))
    assert rec.committed == 8 and rec.pending == 2  # buffered until commit_every
    rec.record(RecordRow(None, 10.0, 1.0e9 + 10, float("nan"), None, "hold", False,
                         channels={"t_spindle_c": float("inf"), "t_ambient_c": 21.5,
                                   "power_kw": 3.0},
                         validity={"t_spindle_c": "out of range", "t_ambient_c": None},
                         contributions={"spindle": 0.0}))
    rec.close()
    assert rec.committed == 11 and rec.dropped == 0 and not rec.alarm
    with contextlib.closing(sqlite3.connect(path)) as conn:
        assert conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    cols = read_samples(path)
    n = 11
    assert all(len(v) == n for v in cols.values())
    assert cols["seq"].tolist() == list(range(1, n + 1))
    assert cols["cycle"].tolist() == [*range(10), -1]
    np.testing.assert_array_equal(cols["time_s"], np.arange(n, dtype=float))
    np.testing.assert_array_equal(cols["t_spindle_c"][:10], 20.0 + np.arange(10))
    assert math.isnan(cols["t_spindle_c"][10])  # inf stored as null -> NaN
    assert cols["offset_um"].dtype == np.float64 and math.isnan(cols["offset_um"][10])
    assert math.isnan(cols["model_um"][10])
    assert np.isnan(cols["power_kw"][:10]).all() and cols["power_kw"][10] == 3.0
    assert cols["valid"].tolist() == [True] * 10 + [False]
    assert cols["valid.t_spindle_c"].tolist() == [True] * 10 + [False]
    assert cols["valid.t_ambient_c"].all()
    assert cols["state"].tolist() == ["ok"] * 10 + ["hold"]
    np.testing.assert_allclose(cols["contribution.spindle"][:10], -0.4 * np.arange(10))
    assert math.isnan(cols["contribution.ambient"][10])


def test_seq_continues_across_reopen(tmp_path: Path) -> None:
    path = tmp_path / "rec.sqlite"
    for start in (0, 5):
        with Recorder(path, commit_every=2) as rec:
            for i in range(start, start + 5):
                rec.record(_row(i))
    assert _seqs(path) == list(range(1, 11))
    cols = read_samples(path)
    assert cols["cycle"].tolist() == list(range(10))


def test_retention_deletes_old_rows(tmp_path: Path) -> None:
    path = tmp_path / "rec.sqlite"
    with Recorder(path, commit_every=1, keep_rows=10, purge_every_commits=5) as rec:
        for i in range(101):
            rec.record(_row(i))
        assert rec.purged > 0
    cols = read_samples(path)
    assert 10 <= len(cols["seq"]) < 10 + 5  # purged every 5 commits
    # what is kept is contiguous
    assert cols["seq"].tolist() == list(range(int(cols["seq"][0]), 102))


def test_retention_never_judged_by_a_jumping_wall_clock(tmp_path: Path) -> None:
    """A PC with a dead clock battery stamps rows in 2000; when the clock is
    corrected, rows within the retention stay (they were all deleted once)."""
    path = tmp_path / "rec.sqlite"
    y2000 = 946684800.0
    with Recorder(path, commit_every=1, keep_rows=50, purge_every_commits=1) as rec:
        for i in range(30):
            rec.record(dataclasses.replace(_row(i), wall_s=y2000 + i))
        for i in range(30, 40):  # the clock is set right: 26 years later
            rec.record(dataclasses.replace(_row(i), wall_s=1.8e9 + i))
        assert rec.purged == 0
    assert len(read_samples(path)["seq"]) == 40
    # and a clock stepped back does not keep more than the retention either
    with Recorder(path, commit_every=1, keep_rows=50, purge_every_commits=1) as rec:
        for i in range(40, 70):
            rec.record(dataclasses.replace(_row(i), wall_s=y2000 - i))
    assert read_samples(path)["seq"].tolist() == list(range(21, 71))


def test_retention_backlog_is_purged_in_bounded_steps(tmp_path: Path) -> None:
    path = tmp_path / "rec.sqlite"
    with Recorder(path, commit_every=500) as rec:
        for i in range(2500):
            rec.record(_row(i))
    with Recorder(path, commit_every=1, keep_rows=3, purge_every_commits=1) as rec:
        rec.record(_row(5000))
        assert rec.purged == 1000  # one bounded step per commit
        rec.record(_row(5001))
        rec.record(_row(5002))
        assert rec.purged == 2500
    assert read_samples(path)["cycle"].tolist() == [5000, 5001, 5002]


def test_not_open_and_bad_path(tmp_path: Path) -> None:
    rec = Recorder(tmp_path / "never.sqlite")
    rec.record(_row(0))  # never raises
    assert rec.dropped == 1 and rec.alarm and rec.last_error
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(RecorderError) as info:
        Recorder(blocker / "rec.sqlite").open()
    assert isinstance(info.value, CompdError) and str(blocker) in str(info.value)
    with pytest.raises(InputError, match="No such file"):  # exit 66, as any missing input
        read_samples(tmp_path / "missing.sqlite")
    junk = tmp_path / "junk.sqlite"
    junk.write_bytes(b"not a database at all" * 100)
    with pytest.raises(RecorderError):
        read_samples(junk)
    with pytest.raises(ValueError):
        Recorder(tmp_path / "x.sqlite", commit_every=0)


_WRITER = """
import sys
from pathlib import Path
from compd.runtime.recorder import Recorder, RecordRow
rec = Recorder(Path(sys.argv[1]), commit_every=int(sys.argv[2]))
rec.open()
out = sys.stdout
i = 0
while True:
    i += 1
    rec.record(RecordRow(mono_s=float(i), wall_s=float(i), offset_um=float(i), model_um=float(i),
                         state="ok", valid=True, channels={"a": float(i), "b": -float(i)},
                         validity={"a": None, "b": None}, contributions={"t": float(i)}, seq=i))
    out.write(f"{i}\\n")
    out.flush()
"""


def test_kill9_loses_at_most_the_last_commit_interval(tmp_path: Path) -> None:
    path = tmp_path / "rec.sqlite"
    commit_every = 10
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    rng = random.Random(3)
    total = 0
    for _ in range(6):
        proc = subprocess.Popen([sys.executable, "-c", _WRITER, str(path), str(commit_every)],
                                stdout=subprocess.PIPE, env=env, cwd=ROOT)
        assert proc.stdout is not None
        lines: list[bytes] = []
        reader = threading.Thread(target=lines.extend, args=(proc.stdout,))
        reader.start()
        while not lines:  # until it records
            time.sleep(0.005)
        time.sleep(rng.uniform(0.0, 0.15))
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        reader.join()
        proc.stdout.close()
        complete = [int(x) for x in lines if x.endswith(b"\n")]
        returned = complete[-1]  # record() calls known to have returned
        with contextlib.closing(sqlite3.connect(path)) as conn:
            assert conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        cols = read_samples(path)
        kept = len(cols["seq"]) - total
        # everything committed is there; only the open commit interval is lost
        assert returned - (commit_every - 1) <= kept <= returned + 1
        assert kept % commit_every == 0
        assert cols["seq"].tolist() == list(range(1, total + kept + 1))  # no hole
        np.testing.assert_array_equal(cols["a"][total:], np.arange(1, kept + 1))
        np.testing.assert_array_equal(cols["cycle"][total:], np.arange(1, kept + 1))
        total += kept
    assert total > 0


@pytest.fixture
def small_fs(tmp_path: Path) -> Iterator[Path]:
    """A 256 KiB tmpfs: a file system that really runs out of space (ENOSPC)."""
    with small_tmpfs(tmp_path, "256k") as mnt:
        yield mnt


def test_disk_full_counts_drops_raises_alarm_and_recovers(small_fs: Path) -> None:
    path = small_fs / "rec.sqlite"
    rec = Recorder(path, commit_every=5)
    rec.open()
    recorded = 0

    def record(n: int) -> None:
        nonlocal recorded
        for _ in range(n):
            rec.record(_row(recorded, note_c=float(recorded)))
            recorded += 1

    record(20)
    assert rec.committed == 20 and not rec.alarm
    filler = fill(small_fs)
    record(200)  # nothing escapes
    rec.flush()
    assert rec.alarm
    assert rec.dropped > 0
    assert rec.last_error is not None and "full" in rec.last_error.lower()
    assert rec.committed + rec.dropped + rec.pending == recorded
    committed_when_full = rec.committed

    filler.unlink()  # space returns
    record(10)
    rec.flush()
    assert not rec.alarm
    assert rec.committed == committed_when_full + 10
    rec.close()
    assert rec.committed + rec.dropped == recorded
    with contextlib.closing(sqlite3.connect(path)) as conn:
        assert conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    cols = read_samples(path)
    assert cols["seq"].tolist() == list(range(1, rec.committed + 1))
    assert cols["cycle"][-1] == recorded - 1
