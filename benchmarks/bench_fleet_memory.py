"""Resident memory per added machine: `compd run DIR` (one process, every machine a
task of one event loop) against one `compd run FILE` process per machine.

N simulated Modbus machines are served by a sim farm process (the fleet
benchmark's, `bench_daemon_fleet.py --sim-farm`); each mode runs its daemons
through the real command line for --settle seconds, then VmRSS is read (the
one process; the sum over the N processes), counted from when every daemon has
taken its state lock, and SIGTERM stops them; every
machine must have written its checkpoint at the stop and exited 0, otherwise
the step is reported failed. Per added machine = (RSS(N) - RSS(1)) / (N - 1)
with RSS(1) the one-machine figure of the same mode in the same run.
Target: <= 5 MB per machine after the first (500 machines per PC).

Run:  .venv/bin/python benchmarks/bench_fleet_memory.py [--machines 64] [--settle 15]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from daemon_bench_common import config_doc, rss_mb, write_config

HERE = Path(__file__).resolve().parent


def _configs(descs: list[dict[str, Any]], d: Path) -> list[Path]:
    d.mkdir(parents=True)
    paths = []
    for i, desc in enumerate(descs):
        doc = config_doc(desc, state_dir=d / f"state{i}", checkpoint_every=1_000_000)
        doc["machine"]["name"] = f"machine-{i:04d}"
        paths.append(write_config(doc, d / f"machine{i:04d}.toml"))
    return paths


def _stop(procs: list[subprocess.Popen[bytes]]) -> list[int]:
    for p in procs:
        p.send_signal(signal.SIGTERM)
    rcs = []
    for p in procs:
        try:
            rcs.append(p.wait(120))
        except subprocess.TimeoutExpired:
            p.kill()
            rcs.append(p.wait())
    return rcs


def measure(paths: list[Path], one_process: bool, settle_s: float, logs: Path) -> float:
    """Total VmRSS (MB) of the daemons serving `paths`; raises when one failed."""
    cmd = [sys.executable, "-m", "compd", "run"]
    env = {**os.environ, "NOTIFY_SOCKET": ""}
    with (logs / f"{'one' if one_process else 'each'}-{len(paths)}.log").open("wb") as log:
        argv = [[*cmd, str(paths[0].parent)]] if one_process else [[*cmd, str(p)]
                                                                    for p in paths]
        procs = [subprocess.Popen(a, stdin=subprocess.DEVNULL, stdout=log, stderr=log,
                                  env=env) for a in argv]
        try:
            # every daemon started (its lock taken: signal handlers in place), then settle
            deadline = time.monotonic() + 600.0
            while time.monotonic() < deadline and not all(
                    (p.parent / f"state{int(p.stem[7:])}" / "compd.lock").exists()
                    for p in paths):
                time.sleep(0.5)
            time.sleep(settle_s)
            rss = sum(rss_mb(p.pid) for p in procs)
        finally:
            rcs = _stop(procs)
    missing = [p for p in paths
               if not (p.parent / f"state{int(p.stem[7:])}" / "checkpoint.json").exists()]
    if any(rcs) or missing:
        raise RuntimeError(f"exit {rcs[:5]}, {len(missing)} of {len(paths)} machines "
                           f"without a checkpoint (logs in {logs})")
    return rss


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--machines", type=int, default=64)
    parser.add_argument("--settle", type=float, default=15.0,
                        help="seconds the daemons cycle before RSS is read")
    args = parser.parse_args()
    n = args.machines
    farm = subprocess.Popen([sys.executable, str(HERE / "bench_daemon_fleet.py"),
                             "--sim-farm", "modbus", "--count", str(n)],
                            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, text=True)
    try:
        line = farm.stdout.readline() if farm.stdout else ""
        if not line:
            raise RuntimeError(f"the sim farm exited {farm.wait()}")
        descs = json.loads(line)
        load = Path("/proc/loadavg").read_text().split()[:3]
        print(f"{n} simulated Modbus machines at 1 Hz, {args.settle:.0f} s settle, "
              f"load average before: {' '.join(load)}")
        with tempfile.TemporaryDirectory(prefix="bench-fleet-memory-") as tmp:
            rows = []
            for one_process in (True, False):
                name = "compd run DIR (one process)" if one_process else \
                    "compd run FILE x N (process each)"
                r1 = measure(_configs(descs[:1], Path(tmp) / f"{one_process}-1"),
                             one_process, args.settle, Path(tmp))
                rn = measure(_configs(descs, Path(tmp) / f"{one_process}-{n}"),
                             one_process, args.settle, Path(tmp))
                rows.append((name, r1, rn, (rn - r1) / (n - 1)))
                print(f"  {name:36s} RSS 1: {r1:7.1f} MB  RSS {n}: {rn:8.1f} MB  "
                      f"per added machine: {(rn - r1) / (n - 1):6.2f} MB", flush=True)
            load = Path("/proc/loadavg").read_text().split()[:3]
            print(f"load average after: {' '.join(load)}; ratio process-each / one-process "
                  f"per added machine: {rows[1][3] / rows[0][3]:.1f}x")
    finally:
        farm.terminate()
        farm.wait(60)


if __name__ == "__main__":
    main()
