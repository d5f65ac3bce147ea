"""The process's disk thread (`compd.runtime.diskwriter`) and what runs on it:
checkpoint saves and recorder commits, in order, flushed on stop, their
errors reported as when they ran on the loop's thread."""

from __future__ import annotations

import asyncio
import sqlite3
import threading
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace
from typing import Any, cast

import pytest

from compd.core.record import RecordRow
from compd.runtime.checkpoint import CHECKPOINT_NAME, load_checkpoint
from compd.runtime.diskwriter import DiskWriter
from compd.runtime.recorder import Recorder
from compd.runtime.sinks.checkpoint import CheckpointSink
from compd.runtime.sinks.recorder import RecorderSink
from compd.runtime.statedir import StateDirError


def test_jobs_run_in_order_on_one_thread_and_drain_waits_for_them() -> None:
    writer = DiskWriter()
    gate = threading.Event()
    done: list[tuple[int, str]] = []
    writer.submit(gate.wait)  # hold the thread until every job is queued

    def job(k: int) -> Callable[[], None]:
        return lambda: done.append((k, threading.current_thread().name))

    futures = [writer.submit(job(k)) for k in range(50)]
    assert done == []
    gate.set()
    writer.drain()
    assert all(f.done() for f in futures)
    assert [k for k, _ in done] == list(range(50))
    assert {name for _, name in done} == {done[0][1]} != {threading.current_thread().name}
    writer.shutdown()


def test_other_keys_run_beside_a_slow_job() -> None:
    """One machine's slow fsync does not hold the others' saves: a job of another
    key runs while the first still waits (the first would wait forever in a
    single queue; it gives up after 10 s and the test fails)."""
    writer = DiskWriter(threads=4)
    keys = [f"/var/lib/compd/m{k}" for k in range(16)]
    slow_key = keys[0]
    other = next(k for k in keys if hash(k) % 4 != hash(slow_key) % 4)
    released = threading.Event()
    slow = writer.submit(lambda: released.wait(10.0), key=slow_key)
    writer.submit(released.set, key=other).result()
    assert slow.result() is True
    writer.shutdown()


def test_a_failing_job_reports_on_its_future_and_the_next_ones_run() -> None:
    writer = DiskWriter()

    def boom() -> None:
        raise OSError(28, "No space left on device")

    bad = writer.submit(boom)
    good = writer.submit(lambda: 7)
    with pytest.raises(OSError, match="No space"):
        bad.result()
    assert good.result() == 7
    writer.shutdown()


def row(seq: int) -> RecordRow:
    return RecordRow(seq=seq, mono_s=float(seq), wall_s=1.7e9 + seq, offset_um=0.1 * seq,
                     model_um=0.1 * seq, state="ok", valid=True,
                     channels={"bearing": 20.0 + 0.01 * seq}, validity={"bearing": None},
                     contributions={"t1": 0.1 * seq}, attempted_um=0.1 * seq, complete=True)


def rows_in(path: Path) -> list[int]:
    with sqlite3.connect(path) as conn:
        return [r[0] for r in conn.execute("SELECT cycle FROM samples ORDER BY seq")]


def test_recorder_commits_on_the_writer_in_order_and_close_flushes(tmp_path: Path) -> None:
    writer = DiskWriter()
    gate = threading.Event()
    path = tmp_path / "samples.sqlite"
    rec = Recorder(path, commit_every=10, writer=writer)
    rec.open()
    writer.submit(gate.wait, key=str(tmp_path))  # the recorder's thread
    for k in range(1, 11):
        rec.record(row(k))
    assert rec.pending == 0 and rec.committed == 0  # handed over, not committed yet
    assert rows_in(path) == []
    gate.set()
    for k in range(11, 26):  # the batch of 11..20 waits for 1..10, never beside it
        rec.record(row(k))
    rec.close()  # the batch in flight, then the 5 buffered rows
    assert rec.committed == 25 and rec.dropped == 0
    assert rows_in(path) == list(range(1, 26))
    writer.shutdown()


def test_never_more_rows_uncommitted_than_one_commit_interval(tmp_path: Path) -> None:
    """A crash loses at most `commit_every` rows, as when the loop committed: the
    next batch is handed over only once the one before it is committed."""
    writer = DiskWriter()
    gate = threading.Event()
    rec = Recorder(tmp_path / "samples.sqlite", commit_every=5, writer=writer)
    rec.open()
    writer.submit(gate.wait, key=str(tmp_path))
    for k in range(1, 6):
        rec.record(row(k))
    assert rec.committed == 0 and rec.pending == 0  # 1..5 in flight
    gate.set()
    rec.record(row(6))  # joins the buffer only once 1..5 are committed
    assert rec.committed == 5 and rec.pending == 1
    for k in range(7, 11):
        rec.record(row(k))
        assert rec.committed + rec.pending <= k  # never above one interval uncommitted
    rec.close()
    assert rec.committed == 10
    writer.shutdown()


def test_a_commit_failing_on_the_writer_is_counted_and_alarmed(tmp_path: Path,
                                                                 monkeypatch: pytest.MonkeyPatch
                                                                 ) -> None:
    writer = DiskWriter()
    path = tmp_path / "samples.sqlite"
    rec = Recorder(path, commit_every=3, writer=writer)
    rec.open()

    def refuse(directory: object) -> None:
        raise StateDirError(path, "samples.sqlite-wal is a symbolic link")

    monkeypatch.setattr(rec, "_check", refuse)
    for k in range(1, 4):
        rec.record(row(k))
    writer.drain()
    assert rec.dropped == 3 and rec.alarm
    assert rec.last_error is not None and "symbolic link" in rec.last_error
    monkeypatch.undo()
    for k in range(4, 7):
        rec.record(row(k))
    writer.drain()
    assert not rec.alarm and rec.committed == 3  # the next good commit clears it
    rec.close()
    assert rows_in(path) == [4, 5, 6]
    writer.shutdown()


class Log:
    def __init__(self) -> None:
        self.errors: list[tuple[str, dict[str, object]]] = []

    def error(self, event: str, **kw: object) -> None:
        self.errors.append((event, kw))


def checkpoint_sink(state_dir: Path, writer: DiskWriter, export: Callable[[], dict[str, Any]],
                    log: Log) -> tuple[CheckpointSink, Any, Any]:
    """The sink, its config, and the cycle whose state it saves (`export`)."""
    cfg = SimpleNamespace(raw=SimpleNamespace(state=SimpleNamespace(checkpoint_every=10)),
                          state_dir=state_dir, model_sha256="m", config_sha256="c")
    sink = CheckpointSink(dry_run=False, journal=cast(Any, SimpleNamespace(log=log)),
                          writer=writer)
    return sink, cast(Any, cfg), cast(Any, SimpleNamespace(export_state=export))


def _row(sequence: int, *, healthy: bool = True) -> Any:
    from compd.core.faults import FaultState
    from compd.core.health import Cause

    return SimpleNamespace(state=FaultState.OK, healthy=healthy, sequence=sequence,
                           cause=Cause.IN_FORCE if healthy else Cause.AT_LIMIT,
                           in_force=healthy, wall_s=1000.0 + sequence)


async def test_checkpoint_saves_run_on_the_writer_in_the_order_asked(tmp_path: Path) -> None:
    """The state is taken when the save is asked for; the saves land in that
    order (the last asked is the file), and `save` returns with the file written."""
    writer = DiskWriter()
    gate = threading.Event()
    state = {"sequence": 0}
    sink, cfg, cycle = checkpoint_sink(tmp_path, writer, lambda: dict(state), Log())
    sink.note(cast(Any, SimpleNamespace(row=_row(1), cfg=cfg, mono_s=1.0)))
    writer.submit(gate.wait, key=str(tmp_path))  # the state directory's thread
    first = asyncio.ensure_future(sink.save_async(cfg, cycle))
    await asyncio.sleep(0)
    state["sequence"] = 1  # the cycle goes on: the first save keeps what it took
    second = asyncio.ensure_future(sink.save_async(cfg, cycle))
    await asyncio.sleep(0)
    assert load_checkpoint(tmp_path / CHECKPOINT_NAME) is None  # nothing written yet
    gate.set()
    await asyncio.gather(first, second)
    doc = load_checkpoint(tmp_path / CHECKPOINT_NAME)
    assert doc is not None and doc["sequence"] == 1
    state["sequence"] = 2
    sink.save(cfg, cycle)  # shutdown, --once, a hold: written when it returns
    doc = load_checkpoint(tmp_path / CHECKPOINT_NAME)
    assert doc is not None and doc["sequence"] == 2
    writer.shutdown()


async def test_a_checkpoint_failing_on_the_writer_is_logged_and_tried_again(
        tmp_path: Path) -> None:
    """As on the loop's thread: ``checkpoint_failed`` with the reason, the loop goes
    on, and an unhealthy state still counts as not saved (the next cycle out of
    force saves at once again)."""
    from compd.core.faults import FaultState
    from compd.core.health import Cause

    writer, log = DiskWriter(), Log()
    sink, cfg, cycle = checkpoint_sink(tmp_path / "gone", writer, lambda: {"sequence": 1}, log)
    row = SimpleNamespace(state=FaultState.OK, cause=Cause.AT_LIMIT, healthy=False,
                          sequence=3, in_force=False, wall_s=1000.0)
    tick = cast(Any, SimpleNamespace(row=row, cfg=cfg, mono_s=0.0))
    assert sink.note(tick)  # out of force: due at once
    await sink.save_async(cfg, cycle)
    assert [e for e, _ in log.errors] == ["checkpoint_failed"]
    assert "gone" in str(log.errors[0][1]["error"])
    row.sequence = 4
    assert sink.note(tick)  # still due: nothing was saved
    (tmp_path / "gone").mkdir(mode=0o700)
    await sink.save_async(cfg, cycle)
    assert len(log.errors) == 1
    doc = load_checkpoint(tmp_path / "gone" / CHECKPOINT_NAME)
    assert doc is not None and doc["last_cause"] == "at_limit"
    row.sequence = 5
    assert not sink.note(tick)  # saved unhealthy: not again
    writer.shutdown()


def test_a_new_recorder_file_has_small_pages_and_an_old_one_keeps_its_own(
        tmp_path: Path) -> None:
    """Small pages cut the bytes each commit writes (WAL frames are whole pages); a
    file an older compd made keeps its page size (WAL mode cannot change it) and
    is appended to as before."""
    from compd.runtime.recorder import PAGE_BYTES

    def page_size(path: Path) -> int:
        with sqlite3.connect(path) as conn:
            return int(conn.execute("PRAGMA page_size").fetchone()[0])

    new = tmp_path / "new.sqlite"
    with Recorder(new, commit_every=2) as rec:
        for k in range(1, 5):
            rec.record(row(k))
    assert page_size(new) == PAGE_BYTES == 1024
    old = tmp_path / "old.sqlite"
    with sqlite3.connect(old) as conn:
        conn.execute("PRAGMA page_size=4096")
        conn.execute("PRAGMA journal_mode=WAL")
    for start in (1, 5):
        with Recorder(old, commit_every=2) as rec:
            for k in range(start, start + 4):
                rec.record(row(k))
    assert page_size(old) == 4096
    assert rows_in(old) == list(range(1, 9))


async def test_the_recorder_opens_on_its_disk_thread_while_the_loop_runs(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Opening a new recorder file syncs it to disk (tens of ms on a busy disk); a
    machine starting in `compd run DIR` must not hold the others' cycles meanwhile:
    the open runs on the disk thread and the loop goes on (on the loop's thread the
    open would wait out its 10 s for the loop and the test fails)."""
    loop_ran = threading.Event()
    seen: list[tuple[str, bool]] = []
    real_open = Recorder.open

    def open_slowly(self: Recorder) -> None:
        seen.append((threading.current_thread().name, loop_ran.wait(10.0)))
        real_open(self)

    monkeypatch.setattr(Recorder, "open", open_slowly)
    cfg = SimpleNamespace(
        recorder_path=tmp_path / "state" / "samples.sqlite", period_s=1.0,
        raw=SimpleNamespace(recorder=SimpleNamespace(commit_every=2, retention_days=0)))
    log: list[tuple[Any, ...]] = []
    journal = SimpleNamespace(log=SimpleNamespace(error=lambda *a, **k: log.append(a)))
    sink = RecorderSink(dry_run=False, metrics=cast(Any, None), journal=cast(Any, journal))
    opening = asyncio.create_task(sink.open(cast(Any, cfg)))
    await asyncio.sleep(0)  # the open has started
    loop_ran.set()
    await opening
    assert len(seen) == 1 and seen[0][0].startswith("compd-disk") and seen[0][1]
    assert sink.recorder is not None and sink.recorder.is_open and log == []
    for seq in (1, 2):
        sink.recorder.record(row(seq))
    sink.close_now()
    assert rows_in(cfg.recorder_path) == [1, 2]
