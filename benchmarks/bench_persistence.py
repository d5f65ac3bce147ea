"""Per-cycle cost of the daemon's persistence and telemetry, each against a
named peer measured in the same run.

1. `Recorder.record` (commit every 10 rows, WAL, synchronous=NORMAL), per
   row, against bare `sqlite3` executemany of already-built tuples into the
   same schema with the same commit interval (the cost of JSON encoding and
   bookkeeping on top of SQLite).
2. `save_checkpoint` (temp file, fsync, rename, directory fsync) against a
   plain `json.dump` into the file without fsync (the cost of durability).
3. One JSON log line through `configure_logging` (with the redaction
   processor, a secret registered) against the same structlog chain without
   redaction.

Run: .venv/bin/python benchmarks/bench_persistence.py
"""

from __future__ import annotations

import io
import json
import sqlite3
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import structlog

from compd.faces.telemetry import clear_secrets, configure_logging, register_secret
from compd.runtime.checkpoint import save_checkpoint
from compd.runtime.recorder import Recorder, RecordRow, _tuple
from compd.store.schema import INSERT_SAMPLE, SCHEMA


def _per_call(fn: Callable[[], None], n: int, repeats: int = 5) -> float:
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        best = min(best, (time.perf_counter() - t0) / n)
    return best


def _row(i: int) -> RecordRow:
    chans = {f"t{k}_c": 20.0 + 0.01 * i + k for k in range(6)}
    return RecordRow(i, float(i), 1.7e9 + i, -0.5, -0.5, "ok", True, chans,
                     dict.fromkeys(chans), {"spindle": -0.4, "ambient": -0.1})


def bench_recorder(tmp: Path, n: int = 20_000) -> tuple[float, float]:
    rows = [_row(i) for i in range(n)]
    rec = Recorder(tmp / "rec.sqlite", commit_every=10)
    rec.open()
    it = iter(rows * 10)
    ours = _per_call(lambda: rec.record(next(it)), n, repeats=3)
    rec.close()

    conn = sqlite3.connect(tmp / "peer.sqlite", isolation_level=None)
    conn.execute("PRAGMA journal_mode=WAL")
    conn.execute("PRAGMA synchronous=NORMAL")
    conn.executescript(SCHEMA)
    tuples = [_tuple(i + 1, r) for i, r in enumerate(rows)]
    batches = [tuples[i:i + 10] for i in range(0, n, 10)]

    def peer() -> None:
        conn.execute("DELETE FROM samples")
        for batch in batches:
            conn.execute("BEGIN")
            conn.executemany(INSERT_SAMPLE, batch)
            conn.execute("COMMIT")

    peer_s = _per_call(peer, 1, repeats=3) / n
    conn.close()
    return ours, peer_s


def bench_checkpoint(tmp: Path, n: int = 200) -> tuple[float, float]:
    state = {"model": {"terms": {"a": {"x": [0.1] * 12, "y": [0.2] * 12},
                                 "b": {"x": [0.3] * 12, "y": [0.4] * 12}},
                       "references": {"t_spindle_c": 21.0}},
             "offset_um": -3.2, "saved_mono_s": 100.0, "sequence": 42,
             "model_sha256": "ab" * 32, "config_sha256": "cd" * 32}
    path = tmp / "state.json"
    ours = _per_call(lambda: save_checkpoint(path, state), n, repeats=3)
    plain = tmp / "plain.json"

    def peer() -> None:
        with plain.open("w") as f:
            json.dump(state, f)

    return ours, _per_call(peer, n, repeats=3)


def bench_log(n: int = 20_000) -> tuple[float, float]:
    sink = io.StringIO()
    configure_logging(json=True, stream=sink)
    register_secret("hunter2-secret")
    log = structlog.get_logger()

    def line() -> None:
        log.info("cycle_overrun", late_s=0.012, sequence=12345, channel="t_spindle_c")
        sink.seek(0)
        sink.truncate()

    ours = _per_call(line, n)
    structlog.configure(processors=[
        structlog.processors.add_log_level,
        structlog.processors.TimeStamper(fmt="iso", utc=True),
        structlog.processors.JSONRenderer()],
        logger_factory=structlog.PrintLoggerFactory(file=sink))
    log = structlog.get_logger()
    peer = _per_call(line, n)
    clear_secrets()
    return ours, peer


def main() -> None:
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        ours, peer = bench_recorder(tmp)
        print(f"recorder.record per row: {ours * 1e6:.1f} µs; bare sqlite3 executemany "
              f"{peer * 1e6:.1f} µs; ratio {ours / peer:.2f}x")
        ours, peer = bench_checkpoint(tmp)
        print(f"save_checkpoint: {ours * 1e3:.3f} ms; json.dump without fsync "
              f"{peer * 1e3:.3f} ms; ratio {ours / peer:.1f}x")
    ours, peer = bench_log()
    print(f"JSON log line with redaction: {ours * 1e6:.1f} µs; without {peer * 1e6:.1f} µs; "
          f"ratio {ours / peer:.2f}x")


if __name__ == "__main__":
    main()
