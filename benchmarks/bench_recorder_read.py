"""Peak memory of `compd replay` and `compd export` on a recorder database of the
size the default retention makes (30 days at 1 s: ~600 MiB), against the same
commands on a database an eighth of its size in the same run; and the bytes
per row of the recorder's layout against the previous one (every channel value
twice: the JSON column and table channel_values).

The databases are written by the recorder itself (`Recorder`, one transaction
per 100,000 rows) in a temporary directory: five channels (bearing, motor,
column, ambient, speed_rpm), four terms, one row per second with contiguous
cycles, so `compd replay sp2 DB --column model_um` takes it as a record. Each
command runs as a child process (`python -m compd`); its peak RSS is the
child's own, as `/usr/bin/time -f %M` reports it. With `--also REV` the same commands of git
revision REV run too (its packages unpacked by `git archive`), e.g. the
reader before this one, which refused a file over 512 MiB (exit 65).

Run: .venv/bin/python benchmarks/bench_recorder_read.py [--mib 600] [--also REV] [--dir DIR]
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import random
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from compd.runtime.recorder import Recorder, RecordRow

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from tests.compd.store.recorder_layouts import write_previous  # noqa: E402

CHANNELS = ("bearing", "motor", "column", "ambient", "spindle_rpm")
TERMS = ("spindle", "motor", "column", "ambient")
T0 = 1_795_000_000.0
COMMIT_ROWS = 100_000


def row(k: int, rng: random.Random) -> RecordRow:
    """Second `k` of a machine day: slow thermal drifts with sensor noise."""
    h = k / 3600.0
    chans: dict[str, float | None] = {
        "bearing": 24.0 + 6.0 * math.sin(h / 3.0) + rng.gauss(0.0, 0.02),
        "motor": 30.0 + 8.0 * math.sin(h / 2.0 + 1.0) + rng.gauss(0.0, 0.02),
        "column": 21.0 + 1.5 * math.sin(h / 5.0) + rng.gauss(0.0, 0.02),
        "ambient": 20.0 + 2.0 * math.sin(2 * math.pi * h / 24.0) + rng.gauss(0.0, 0.02),
        "spindle_rpm": float(rng.choice((0, 3000, 6000, 9000)) if k % 600 == 0 else 0)}
    contributions = {t: rng.gauss(0.0, 4.0) for t in TERMS}
    total = sum(contributions.values())
    return RecordRow(seq=k, mono_s=float(k), wall_s=T0 + k, offset_um=total, model_um=total,
                     state="ok", valid=True, channels=chans, validity=dict.fromkeys(chans),
                     contributions=contributions, attempted_um=total, complete=True)


def settled_size(path: Path) -> int:
    """The file's size once the WAL is folded into it."""
    with contextlib.closing(sqlite3.connect(path)) as conn:
        conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    return path.stat().st_size


def write_rows(path: Path, n: int, seed: int = 1) -> int:
    rng = random.Random(seed)
    with Recorder(path, commit_every=COMMIT_ROWS) as rec:
        for k in range(n):
            rec.record(row(k, rng))
    return settled_size(path)


def rows_in(path: Path) -> int | None:
    if not path.is_file():
        return None
    with contextlib.closing(sqlite3.connect(path)) as conn:
        return int(conn.execute("SELECT COUNT(*) FROM samples").fetchone()[0])


def bytes_per_row(tmp: Path, n: int = 50_000) -> tuple[float, float]:
    """(today's layout, the previous layout) bytes per row, same rows."""
    rng = random.Random(1)
    rows = [row(k, rng) for k in range(n)]
    write_previous(tmp / "previous.sqlite", rows)
    with Recorder(tmp / "now.sqlite", commit_every=COMMIT_ROWS) as rec:
        for r in rows:
            rec.record(r)
    return (settled_size(tmp / "now.sqlite") / n, settled_size(tmp / "previous.sqlite") / n)


def run_child(argv: list[str], pythonpath: Path | None = None) -> tuple[int, float, float, str]:
    """(exit status, peak RSS MiB, seconds, last line of stderr) of `python -m compd
    ARGV`, its peak RSS as /usr/bin/time reports it (the child's ru_maxrss read by
    this process would count this process's own size, which the fork copies)."""
    env = dict(os.environ)
    if pythonpath is not None:
        env["PYTHONPATH"] = str(pythonpath)
    with tempfile.TemporaryDirectory() as d:
        rss_file, err_file = Path(d) / "rss", Path(d) / "err"
        t0 = time.perf_counter()
        with err_file.open("wb") as err:
            # cwd: not the checkout, whose compd/ python -m would import before PYTHONPATH's
            rc = subprocess.run(["/usr/bin/time", "-f", "%M", "-o", str(rss_file),
                                 sys.executable, "-m", "compd", *argv], env=env, cwd=d,
                                stdout=subprocess.DEVNULL, stderr=err, check=False).returncode
        secs = time.perf_counter() - t0
        rss_kib = float(rss_file.read_text().split()[-1])
        last = (err_file.read_text(errors="replace").strip().splitlines() or [""])[-1]
    return rc, rss_kib / 1024.0, secs, last


def commands(db: Path, out: Path) -> dict[str, list[str]]:
    return {"replay": ["replay", "sp2", str(db), "--column", "model_um", "--json"],
            "export": ["export", str(db), "-o", str(out), "--force"]}


def unpack(rev: str, into: Path) -> Path:
    into.mkdir()
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "compd", "drivers",
                              "models"], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    return into


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--mib", type=float, default=600.0, help="size of the large database")
    parser.add_argument("--also", metavar="REV", default=None,
                        help="also run the commands of this git revision")
    parser.add_argument("--dir", type=Path, default=None,
                        help="write the databases here and keep them; a later run with the "
                             "same --dir and --mib reuses them (default: a temporary directory)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(dir=os.environ.get("TMPDIR")) as d:
        tmp = Path(d)
        keep = args.dir or tmp
        keep.mkdir(parents=True, exist_ok=True)
        now_b, prev_b = bytes_per_row(tmp)
        print(f"bytes per row (5 channels, 4 terms): {now_b:.0f} now, {prev_b:.0f} previous "
              f"layout (values twice): {prev_b / now_b:.2f}x, {1 - now_b / prev_b:.0%} less")
        rows = int(args.mib * (1 << 20) / now_b)
        dbs = {}
        for name, n in (("large", rows), ("eighth", rows // 8)):
            db = keep / f"{name}.db"
            t0 = time.perf_counter()
            if rows_in(db) != n:
                db.unlink(missing_ok=True)
                size = write_rows(db, n)
                how = f"written in {time.perf_counter() - t0:.0f} s"
            else:
                size, how = settled_size(db), "kept from an earlier run"
            dbs[name] = (db, n, size)
            print(f"{name}: {n:,} rows, {size / (1 << 20):.0f} MiB, {how}")
        revs: list[tuple[str, Path | None]] = [("this tree", None)]
        if args.also:
            revs.append((args.also, unpack(args.also, tmp / "rev")))
        peak: dict[tuple[str, str, str], float] = {}
        for label, path in revs:
            for name, (db, n, size) in dbs.items():
                for cmd, argv in commands(db, tmp / "out.csv").items():
                    rc, rss, secs, last = run_child(argv, path)
                    peak[(label, name, cmd)] = rss
                    note = "" if rc == 0 else f"  ({last[:90]})"
                    print(f"{label:>10} {cmd:>6} {name:>6} ({size / (1 << 20):4.0f} MiB): "
                          f"exit {rc}, peak RSS {rss:6.1f} MiB, {rss * (1 << 20) / size:5.2f} "
                          f"of the file's size, {rss * (1 << 20) / n:5.0f} B/row, {secs:5.1f} s"
                          f"{note}")
                (tmp / "out.csv").unlink(missing_ok=True)
        for cmd in ("replay", "export"):
            ratio = peak[("this tree", "large", cmd)] / peak[("this tree", "eighth", cmd)]
            print(f"{cmd}: peak RSS large / eighth = {ratio:.2f} (the file is 8x)")


if __name__ == "__main__":
    main()
