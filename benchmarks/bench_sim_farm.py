"""What one simulated controller costs in the fleet benchmark's sim farm: seconds
to start and resident MB per simulated server.

Starts the farm exactly as `bench_daemon_fleet.py` does (that script with
``--sim-farm PROTOCOL --count N``, one process), for each N of --counts in turn;
the farm is ready when it prints its controllers' descriptions. Per N it prints
the wall seconds to ready, the farm's CPU seconds and RSS at ready, and, against
the smallest N, the MB and seconds each further server added.

Run:  .venv/bin/python benchmarks/bench_sim_farm.py [--protocol opcua] [--counts 1 16 64]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

from daemon_bench_common import cpu_s, rss_mb, stop_processes

FLEET = Path(__file__).resolve().with_name("bench_daemon_fleet.py")


def measure(protocol: str, count: int) -> tuple[float, float, float]:
    """(wall s to ready, CPU s to ready, RSS MB at ready) of one farm of `count`."""
    t0 = time.monotonic()
    farm = subprocess.Popen(
        [sys.executable, str(FLEET), "--sim-farm", protocol, "--count", str(count)],
        stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
        text=True)
    try:
        line = farm.stdout.readline() if farm.stdout else ""
        wall = time.monotonic() - t0
        if not line:
            raise RuntimeError(f"the sim farm exited {farm.wait()}")
        return wall, cpu_s(farm.pid), rss_mb(farm.pid)
    finally:
        stop_processes([farm])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--protocol", default="opcua")
    ap.add_argument("--counts", type=int, nargs="+", default=[1, 16, 64])
    args = ap.parse_args()
    counts = sorted(set(args.counts))
    load = Path("/proc/loadavg").read_text().split()[0]
    print(f"{args.protocol} sim farm, one process; load {load}")
    print(f"{'servers':>8}{'wall s':>9}{'CPU s':>9}{'RSS MB':>9}"
          f"{'MB/server':>11}{'CPU s/server':>14}")
    first: tuple[float, float, float] | None = None
    for n in counts:
        wall, cpu, rss = measure(args.protocol, n)
        if first is None:
            first = (float(n), cpu, rss)
            per = ""
        else:
            k = n - first[0]
            per = f"{(rss - first[2]) / k:11.2f}{(cpu - first[1]) / k:14.3f}"
        print(f"{n:8d}{wall:9.1f}{cpu:9.1f}{rss:9.0f}{per}", flush=True)


if __name__ == "__main__":
    main()
