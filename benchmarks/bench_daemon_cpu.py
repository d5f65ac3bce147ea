"""CPU seconds per daemon cycle, in-process, against the same measure of
another checkout of compd (the peer), alternating, in the same run.

The daemon (`compd.runtime.daemon.Daemon`, recorder on, checkpoint every 20,
JSON logs at info to /dev/null) runs against `compd.testing.MemoryDriver` on a
`compd.testing.SteppedClock`: no sockets and no deadlines, so what is
measured is the shell's own work per cycle (read, step, write, sinks,
amortised checkpoint), as CPU time (`time.process_time`), which a loaded
machine moves less than wall time. Each round runs this checkout and the
peer's in fresh processes, one after the other; the medians and their ratio
are printed.

Run:  .venv/bin/python benchmarks/bench_daemon_cpu.py --peer /path/to/old/checkout
      [--cycles 5000] [--rounds 4]
(a peer checkout: ``git worktree add /tmp/compd-old REV``; it runs with this
venv, its own code first on PYTHONPATH).
"""

from __future__ import annotations

import argparse
import asyncio
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve()
ROOT = HERE.parent.parent
WARMUP = 200


def _measure(cycles: int) -> float:
    from compd.faces.telemetry import configure_logging

    with tempfile.TemporaryDirectory() as tmp, open(os.devnull, "w") as devnull:
        configure_logging(json=True, level="info", stream=devnull)
        return asyncio.run(_cycles(cycles, Path(tmp)))


async def _cycles(cycles: int, tmp: Path) -> float:
    from compd.config.loader import load_config
    from compd.runtime.daemon import Daemon
    from compd.runtime.sdnotify import Notifier
    from compd.testing import MemoryDriver, SteppedClock
    from tests.configs import write_config

    cfg = load_config(write_config(tmp, "127.0.0.1:1", time_scale=1.0, timeout_s=0.4))
    clock = SteppedClock(period_s=cfg.period_s)

    def wall() -> float:
        return 1.7e9 + clock()

    driver = MemoryDriver({"bearing": 20.0, "ambient": 20.0},
                          ("offset", "heartbeat", "status"), wall=wall)
    daemon = Daemon(cfg, driver=driver, notifier=Notifier(None), clock=clock, wall=wall,
                    sleep=clock.sleep)
    task = asyncio.create_task(daemon.run())
    await clock.cycle_done(1)
    t0 = 0.0
    for k in range(1, cycles):
        if k == WARMUP:
            t0 = time.process_time()
        driver.set("bearing", 20.0 + 0.001 * (k % 500))
        clock.tick()
        await clock.cycle_done(k + 1)
    cpu = time.process_time() - t0
    daemon.request_stop()
    if await task != 0:
        raise SystemExit("the daemon did not stop cleanly")
    return cpu / (cycles - WARMUP)


def _one(tree: Path, cycles: int) -> float:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    out = subprocess.run([sys.executable, str(HERE), "--measure", str(cycles)], cwd=tree,
                         env=env, capture_output=True, text=True, check=True)
    return float(out.stdout.split()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--peer", type=Path, help="another checkout of compd")
    parser.add_argument("--cycles", type=int, default=5000)
    parser.add_argument("--rounds", type=int, default=4)
    parser.add_argument("--measure", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.measure:
        sys.path.insert(0, os.getcwd())
        print(f"cpu_s_per_cycle {_measure(args.measure)!r}")
        return
    if args.peer is None:
        parser.error("--peer is required")
    ours: list[float] = []
    peer: list[float] = []
    for r in range(args.rounds):
        peer.append(_one(args.peer.resolve(), args.cycles))
        ours.append(_one(ROOT, args.cycles))
        print(f"round {r + 1}: peer {peer[-1] * 1e6:.1f} us, this {ours[-1] * 1e6:.1f} us "
              "CPU per cycle", flush=True)
    a, b = statistics.median(ours), statistics.median(peer)
    print(f"\nmedian CPU per cycle over {args.cycles - WARMUP} cycles x {args.rounds} rounds: "
          f"this {a * 1e6:.1f} us, peer ({args.peer}) {b * 1e6:.1f} us, ratio {a / b:.3f}")


if __name__ == "__main__":
    main()
