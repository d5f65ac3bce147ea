"""`compd fit` against the record's length, each length against its own replay.

Records of 1 s data from the simulated plant (`drivers.sim.offline`, the
``spectrum`` program, seed 3: deterministic) of 1 h, 1 day, 1 week and one
month (30 days, 2,592,001 rows), four terms (bearing, motor, column,
ambient; ``--no-fallbacks`` unless ``--fallbacks``: a fallback is the same
fit again on three of the inputs, four more fits of the same kind). Each
length: ``compd fit`` and then ``compd replay`` of the model it wrote, each
in its own process: its wall time, CPU time (user + system) and peak
resident memory (``ru_maxrss`` of that child, from ``os.wait4``). The peer
of a fit is its replay on the same record in the same run (fit / replay is
the ratio printed, of CPU times: on a shared machine the wall time measures
the neighbours too), and the growth with length is printed against the
1-day fit (a fit that streams grows with the rows: the month at <= 31x the
day).

Records are written once into a cache folder (default
``$TMPDIR/compd_bench_fit_length``; a month's CSV is about 140 MB and takes
a few minutes to simulate) and reused.

Run: .venv/bin/python benchmarks/bench_fit_length.py [--lengths 1h,1d,1w,1mo]
     [--cache DIR] [--repeat N] [--fallbacks]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HOURS = {"1h": 1.0, "1d": 24.0, "1w": 24.0 * 7, "1mo": 24.0 * 30}
TERMS = ("bearing", "motor", "column", "ambient")
SEED = 3


def record(cache: Path, length: str) -> Path:
    """The cached CSV of `length` (written on first use)."""
    from drivers.sim.offline import record_program
    from drivers.sim.programs import spectrum

    path = cache / f"spectrum_seed{SEED}_{length}.csv"
    if not path.exists():
        cache.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        rows = record_program(path, spectrum(seed=SEED, hours=HOURS[length]), seed=SEED)
        print(f"  (wrote {path}: {rows} rows in {time.perf_counter() - t0:.0f} s)",
              flush=True)
    return path


def run_child(argv: list[str]) -> tuple[float, float, float, int]:
    """(wall s, CPU s, peak RSS MB, exit status) of one child process."""
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    t0 = time.perf_counter()
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)
    assert proc.stderr is not None
    err = proc.stderr.read()
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        print(f"  {' '.join(argv[2:4])}: exit {proc.returncode}: "
              f"{err.decode(errors='replace').strip()[-400:]}", file=sys.stderr)
    return wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024.0, proc.returncode


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lengths", default="1h,1d,1w,1mo")
    parser.add_argument("--cache", type=Path,
                        default=Path(tempfile.gettempdir()) / "compd_bench_fit_length")
    parser.add_argument("--repeat", type=int, default=1,
                        help="runs per length (the best is printed)")
    parser.add_argument("--fallbacks", action="store_true",
                        help="fit the fallback models too (the same fit again without each "
                             "input: five fits in all; by default --no-fallbacks)")
    args = parser.parse_args()
    lengths = [s.strip() for s in args.lengths.split(",") if s.strip()]
    compd = [sys.executable, "-m", "compd.cli"]
    print(f"load: {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} {os.getloadavg()[2]:.2f}")
    print(f"{'length':>6} {'rows':>9} {'fit s':>7} {'fit cpu':>7} {'fit MB':>6} "
          f"{'replay s':>8} {'rp cpu':>7} {'rp MB':>6} {'fit/replay':>10} {'fit/day':>8}"
          "   (ratios of CPU time: the machine may be shared)")
    day_fit: float | None = None
    with tempfile.TemporaryDirectory() as tmp:
        for length in lengths:
            rec = record(args.cache, length)
            model = Path(tmp) / f"{length}.toml"
            fits, replays = [], []
            for _ in range(args.repeat):
                fits.append(run_child([*compd, "fit", str(rec), "--column", "dz_um",
                                       *(a for t in TERMS for a in ("--term", t)),
                                       "-o", str(model), "--force",
                                       *([] if args.fallbacks else ["--no-fallbacks"])]))
                replays.append(run_child([*compd, "replay", str(model), str(rec),
                                          "--column", "dz_um"]))
            fit = min(fits, key=lambda r: r[1])
            rep = min(replays, key=lambda r: r[1])
            if length == "1d":
                day_fit = fit[1]
            with rec.open() as f:
                rows = sum(1 for _ in f) - 1
            growth = f"{fit[1] / day_fit:7.1f}x" if day_fit else f"{'-':>8}"
            print(f"{length:>6} {rows:>9} {fit[0]:7.1f} {fit[1]:7.1f} {fit[2]:6.0f} "
                  f"{rep[0]:8.1f} {rep[1]:7.1f} {rep[2]:6.0f} {fit[1] / rep[1]:9.1f}x "
                  f"{growth}", flush=True)


if __name__ == "__main__":
    main()
