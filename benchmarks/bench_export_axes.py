"""What the per-axis columns cost `compd export`: CPU seconds of the CSV export of a
recorder with three axes (x, y, z: one ``axes`` row per sample and axis) against
the same samples' export without them (its ``axes`` table emptied), measured
interleaved in the same run (the peer); and the peak of Python's allocations
(tracemalloc) while exporting the whole file against a quarter of it, which
stays the same when the export streams a batch at a time.

The samples are `bench_recorder_read.row`'s (five channels, four terms, one a
second), written by the recorder; the axis rows are inserted with the recorder's
own statement (`INSERT_AXIS`).

Run: .venv/bin/python benchmarks/bench_export_axes.py [--rows 40000] [--rounds 3]
"""

from __future__ import annotations

import argparse
import os
import random
import shutil
import sqlite3
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from benchmarks.bench_recorder_read import T0, row  # noqa: E402
from compd.offline.export import Export, write_csv  # noqa: E402
from compd.runtime.recorder import Recorder  # noqa: E402
from compd.store.schema import INSERT_AXIS  # noqa: E402


def build(path: Path, rows: int) -> None:
    rng = random.Random(1)
    with Recorder(path, commit_every=10_000) as rec:
        for k in range(rows):
            rec.record(row(k, rng))
    with sqlite3.connect(path) as conn:
        first = conn.execute("SELECT MIN(seq) FROM samples").fetchone()[0]
        conn.executemany(INSERT_AXIS, (
            (first + k, axis, "ok", "none", 1, 0.01 * k, 0.01 * k, 0.01 * k, 0.01 * k,
             0.5, 0.5, 0.5, 0.5, 0.0, 100.0 + k % 500 if axis == "x" else None,
             0.01 * k if axis == "x" else None)
            for k in range(rows) for axis in ("x", "y", "z")))
    conn.close()


def export_cpu_s(path: Path, until: float | None = None) -> float:
    start = time.process_time()
    with Export(path, until=until) as export, open(os.devnull, "w", encoding="utf-8") as out:
        write_csv(export, out)
    return time.process_time() - start


def traced_peak_mib(path: Path, until: float | None = None) -> float:
    tracemalloc.start()
    try:
        export_cpu_s(path, until)
        return tracemalloc.get_traced_memory()[1] / 2**20
    finally:
        tracemalloc.stop()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=40_000)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        axes, plain = Path(tmp) / "axes.sqlite", Path(tmp) / "plain.sqlite"
        build(axes, args.rows)
        shutil.copy(axes, plain)
        with sqlite3.connect(plain) as conn:
            conn.execute("DELETE FROM axes")
        conn.close()
        cpu: dict[str, list[float]] = {"axes": [], "plain": []}
        for _ in range(args.rounds):  # interleaved: a busy machine slows both alike
            cpu["plain"].append(export_cpu_s(plain))
            cpu["axes"].append(export_cpu_s(axes))
        best = {k: min(v) for k, v in cpu.items()}
        print(f"{args.rows} samples, CPU s of the CSV export (best of {args.rounds}): "
              f"without axes {best['plain']:.2f}, with x, y, z {best['axes']:.2f}: "
              f"{best['axes'] / best['plain']:.2f}x")
        quarter = T0 + args.rows / 4
        whole, part = traced_peak_mib(axes), traced_peak_mib(axes, until=quarter)
        print(f"traced peak with axes: whole file {whole:.1f} MiB, its first quarter "
              f"{part:.1f} MiB ({whole / part:.2f}x for 4x the rows)")


if __name__ == "__main__":
    main()
