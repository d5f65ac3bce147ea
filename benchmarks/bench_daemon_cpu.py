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

With --modbus N, each measure is N daemons in one process, each with its own
real Modbus driver (`build_driver`) to one of N simulated controllers served
by one sim farm process (bench_daemon_fleet.py's, started once by this script
and shared by every round): the CPU per machine-cycle of a fleet's process,
sockets, pymodbus and asyncio included, the simulated controllers not. The
daemons step together on one `SteppedClock` (a 1 s period at time_scale 0.1:
10 s of the clock a cycle, so a 4 s request timeout that a loaded PC never
reaches: every cycle completes, whatever the load; the incomplete ones are
counted); --cycles counts the cycles of each machine, after 5 of warm-up.
FLEET_LOOP=uvloop runs both sides' daemons on uvloop's event loop (an
experiment: uvloop is not a dependency of compd).

Run:  .venv/bin/python benchmarks/bench_daemon_cpu.py --peer /path/to/old/checkout
      [--cycles 5000] [--rounds 4] [--modbus 1024 --cycles 30]
(a peer checkout: ``git worktree add /tmp/compd-old REV``; it runs with this
venv, its own code first on PYTHONPATH).
"""

from __future__ import annotations

import argparse
import asyncio
import json
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
#: warm-up cycles of each machine with --modbus
FLEET_WARMUP = 5


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


def _measure_fleet(cycles: int, farm: Path) -> float:
    from compd.faces.telemetry import configure_logging

    descs = json.loads(farm.read_text())
    with tempfile.TemporaryDirectory() as tmp, open(os.devnull, "w") as devnull:
        configure_logging(json=True, level="info", stream=devnull)
        if os.environ.get("FLEET_LOOP") == "uvloop":  # an experiment, as in bench_daemon_fleet
            import uvloop  # type: ignore[import-not-found,unused-ignore]

            return float(uvloop.run(_fleet_cycles(cycles, Path(tmp), descs)))
        return asyncio.run(_fleet_cycles(cycles, Path(tmp), descs))


async def _fleet_cycles(cycles: int, tmp: Path, descs: list[dict[str, object]]) -> float:
    sys.path.insert(0, str(HERE.parent))
    from daemon_bench_common import config_doc, write_config

    from compd.config.loader import load_config
    from compd.runtime.daemon import Daemon
    from compd.runtime.driver_setup import build_driver
    from compd.runtime.sdnotify import Notifier
    from compd.testing import SteppedClock

    clock = SteppedClock(period_s=10.0)
    daemons = []
    for i, desc in enumerate(descs):
        doc = config_doc(desc, state_dir=tmp / f"state{i}", time_scale=0.1,
                         checkpoint_every=20)
        doc["machine"]["name"] = f"m{i:05d}"
        doc["controller"]["timeout_s"] = 4.0
        cfg = load_config(write_config(doc, tmp / f"m{i:05d}.toml"))
        daemons.append(Daemon(cfg, driver=build_driver(cfg), notifier=Notifier(None),
                              clock=clock, sleep=clock.sleep, serve_metrics=False))
    n = len(daemons)
    tasks = [asyncio.create_task(d.run()) for d in daemons]
    await clock.cycle_done(n)
    t0 = 0.0
    for k in range(1, cycles + FLEET_WARMUP):
        if k == FLEET_WARMUP:
            t0 = time.process_time()
        clock.tick()
        await clock.cycle_done(n * (k + 1))
    cpu = time.process_time() - t0
    incomplete = sum(d.loop.cycles - d.telemetry.complete_cycles for d in daemons)
    for d in daemons:
        d.request_stop()
    clock.tick()
    if any(rc != 0 for rc in await asyncio.gather(*tasks)):
        raise SystemExit("a daemon did not stop cleanly")
    if incomplete:
        print(f"incomplete cycles {incomplete} of {n * (cycles + FLEET_WARMUP)}")
    return cpu / (cycles * n)


def _one(tree: Path, cycles: int, farm: Path | None = None) -> float:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    extra = ["--farm", str(farm)] if farm is not None else []
    out = subprocess.run([sys.executable, str(HERE), "--measure", str(cycles), *extra],
                         cwd=tree, env=env, capture_output=True, text=True, check=False)
    if out.returncode != 0:
        raise SystemExit(f"a measure in {tree} exited {out.returncode}:\n{out.stderr[-2000:]}")
    for line in out.stdout.splitlines()[:-1]:
        print(f"  {tree.name}: {line}", flush=True)
    return float(out.stdout.split()[-1])


def _start_farm(n: int, work: Path) -> tuple[subprocess.Popen[str], Path]:
    """bench_daemon_fleet.py's sim farm serving `n` simulated Modbus controllers."""
    farm = subprocess.Popen([sys.executable, str(HERE.parent / "bench_daemon_fleet.py"),
                             "--sim-farm", "modbus", "--count", str(n)],
                            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, text=True)
    line = farm.stdout.readline() if farm.stdout else ""
    if not line:
        raise SystemExit(f"the sim farm exited {farm.wait()}")
    path = work / "farm.json"
    path.write_text(line)
    return farm, path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--peer", type=Path, help="another checkout of compd")
    parser.add_argument("--cycles", type=int, default=5000)
    parser.add_argument("--rounds", type=int, default=4)
    parser.add_argument("--modbus", type=int, default=0, metavar="N",
                        help="N daemons on real Modbus drivers to N simulated controllers "
                             "(CPU per machine-cycle; --cycles per machine, e.g. 30)")
    parser.add_argument("--measure", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--farm", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.measure:
        sys.path.insert(0, os.getcwd())
        cpu = (_measure_fleet(args.measure, args.farm) if args.farm is not None
               else _measure(args.measure))
        print(f"cpu_s_per_cycle {cpu!r}")
        return
    if args.peer is None:
        parser.error("--peer is required")
    with tempfile.TemporaryDirectory() as tmp:
        farm_proc, farm = _start_farm(args.modbus, Path(tmp)) if args.modbus else (None, None)
        try:
            ours, peer = _rounds(args, farm)
        finally:
            if farm_proc is not None:
                farm_proc.terminate()
                farm_proc.wait(60)
    a, b = statistics.median(ours), statistics.median(peer)
    what = (f"{args.cycles} cycles x {args.modbus} Modbus machines" if args.modbus
            else f"{args.cycles - WARMUP} cycles")
    print(f"\nmedian CPU per {'machine-' if args.modbus else ''}cycle over {what} x "
          f"{args.rounds} rounds: this {a * 1e6:.1f} us, peer ({args.peer}) {b * 1e6:.1f} us, "
          f"ratio {a / b:.3f}")


def _rounds(args: argparse.Namespace, farm: Path | None) -> tuple[list[float], list[float]]:
    ours: list[float] = []
    peer: list[float] = []
    for r in range(args.rounds):
        peer.append(_one(args.peer.resolve(), args.cycles, farm))
        ours.append(_one(ROOT, args.cycles, farm))
        print(f"round {r + 1}: peer {peer[-1] * 1e6:.1f} us, this {ours[-1] * 1e6:.1f} us "
              f"CPU per {'machine-' if farm else ''}cycle (load "
              f"{Path('/proc/loadavg').read_text().split()[0]})", flush=True)
    return ours, peer


if __name__ == "__main__":
    main()
