"""How many simulated machines one 2-core PC keeps at 1 Hz with p99 lateness < 10 ms.

Layout per step of N machines (everything on this PC, so the simulated
controllers compete with the daemons for the same cores):

- W "sim farm" processes (this script with --sim-farm) serve N simulated
  machines between them: N simulated controllers of the protocol on
  127.0.0.1, each with its own thermal plant ticking at 1 Hz;
- W daemon worker processes (this script with --worker; W = the CPUs, 2 by
  default) each run N/W real `compd.runtime.daemon.Daemon`s on one event loop (recorder
  on, checkpoint every 20 (see --checkpoint-every), JSON logs at info to a
  file). Each worker starts its daemons as `compd run DIR` does
  (`compd.core.schedule.staggered_starts`: at least 10 ms apart, cycles
  spread evenly over the period); --aligned starts them all at once (worst
  case).

Lateness = cycle start - its deadline, from a timing hook around the unchanged
daemon (`daemon_bench_common.TimedDaemon`), over all machines' cycles in a
window that opens 3 s after every daemon of the worker has started cycling
(so that connecting daemons do not count against the others) and lasts
--seconds. A step holds when p99 lateness < 10 ms, no overrun and under 1 % of
cycles incomplete in the window (what happened before it, while the
daemons started, is printed apart as "start"). N grows (doubling from
--start) until a step fails, then one bisection step between the last pass
and the fail; the largest N that held is printed per protocol. The peer for
the ratios is the single machine (N = 1) measured the same way in the same
run. The 1-minute load average is printed per step: other work on the same
cores moves the figures.

Per step it also prints the longest garbage-collector pause in the window (ms,
from `gc.callbacks`) and the count of full (generation 2) collections, the bytes
the daemon processes wrote to disk per cycle (`/proc/self/io` write_bytes over
the window: recorder, checkpoints, logs) and the requests per cycle (socket
sends of the drivers' asyncio transports over the window / cycles).

To find what a step's time goes to, FLEET_ABLATE=disk4,norecorder,nogc (any of
them) runs the daemons with four disk threads (the former default), without the
recorder, or with CPython's own collector thresholds instead of
`compd.runtime.gcpolicy`; with --run-dir, FLEET_LOOP=uvloop runs the pool on
uvloop's event loop (an experiment: uvloop is not a dependency of compd; its
transports are not counted, so req reads 0).
FLEET_DEBUG=1 prints each worker's figures (own time, collections per
generation) and when its window opens (to attach a profiler) on stderr.

With --run-dir, each step is `compd run DIR --workers W` itself (the real
parent, `compd.runtime.workers`, and its workers, or with W = 1 the one-process
`compd.runtime.fleet`) over a directory of N machine files, every W of
--workers in turn at each N of --sizes; the same timing hook is put around
each machine's daemon inside the worker processes (`--pool-worker`). The
window opens 3 s after the log shows every machine's first cycle; CPU and RSS are
those of the parent plus its workers (RSS: the sum, and the largest process);
the simulated controllers are served by --farms processes whatever W is.

Run:  .venv/bin/python benchmarks/bench_daemon_fleet.py [--protocols modbus opcua]
      [--seconds 20] [--start 32] [--max 1024] [--workers 2] [--aligned]
      [--sizes 256 512 768 1024]
(about 2-3 minutes per protocol with the defaults; --seconds 60 for a longer run;
--sizes runs exactly those N, after N = 1, instead of the search).
      .venv/bin/python benchmarks/bench_daemon_fleet.py --run-dir --protocols modbus
      --sizes 2000 --workers 1 2 [--farms 2]
"""

from __future__ import annotations

import argparse
import asyncio
import gc
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import fleet_run_dir
from daemon_bench_common import (
    TimedDaemon,
    TimedDriver,
    config_doc,
    count_sends,
    cpu_s,
    mean,
    percentile,
    rss_mb,
    stop_processes,
    write_config,
)

from compd.core.schedule import staggered_starts

WARMUP_CYCLES = 3
LIMIT_MS = 10.0
HERE = Path(__file__).resolve()


def _watch_gc(who: str, over_ms: float = 20.0) -> None:
    """Log every collection longer than `over_ms` to stderr."""
    t0 = [0.0]

    def on_gc(phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            t0[0] = time.perf_counter()
        elif (ms := (time.perf_counter() - t0[0]) * 1e3) > over_ms:
            print(f"{who}: gc gen {info['generation']} {ms:.0f} ms "
                  f"at {time.strftime('%H:%M:%S')}", file=sys.stderr, flush=True)

    gc.callbacks.append(on_gc)


# -- the sim farm process ----------------------------------------------------------------

async def _sim_farm(protocol: str, count: int) -> None:
    from compd.commands.sim import describe
    from drivers.sim.base import SimController
    from drivers.sim.machine import SimMachine
    from drivers.sim.programs import make_program
    from drivers.sim.registry import make_sim_controller

    async def started() -> SimController:
        # the free port is chosen before the bind: another farm may take it first
        for attempt in range(10):
            sim = make_sim_controller(protocol)
            try:
                await sim.start()
            except (OSError, RuntimeError):  # pymodbus: RuntimeError "Could not start listen"
                if attempt == 9:
                    raise
                continue
            return sim
        raise RuntimeError("unreachable")

    sims = list(await asyncio.gather(*(started() for _ in range(count))))
    machines = [SimMachine(s, program=make_program("spectrum", seed=i), seed=i)
                for i, s in enumerate(sims)]
    try:
        for m in machines:
            await m.prime()
        for m in machines:
            m.start()
        # the farm is the test harness: its collections (50-100 ms with 500 simulated
        # controllers) would stall every controller at once, which no real shop sees
        gc.freeze()
        _watch_gc("sim farm")
        print(json.dumps([describe(s) for s in sims]), flush=True)
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(sig, stop.set)
        await stop.wait()
    finally:
        for m in machines:
            await m.stop()
        await asyncio.gather(*(s.stop() for s in sims), return_exceptions=True)


# -- a daemon worker process -------------------------------------------------------------

def _write_bytes() -> int:
    """Bytes this process has caused to be written to storage (/proc/self/io)."""
    for line in Path("/proc/self/io").read_text().splitlines():
        if line.startswith("write_bytes:"):
            return int(line.split()[1])
    return 0


async def _worker(configs: list[str], offsets_s: list[float], seconds: int) -> dict[str, Any]:
    from compd.config.loader import load_config
    from compd.runtime.driver_setup import build_driver

    sends = count_sends()

    daemons: list[TimedDaemon] = []
    drivers: list[TimedDriver] = []
    for path in configs:
        cfg = load_config(path)
        drv = TimedDriver(build_driver(cfg))
        d = TimedDaemon(cfg, driver=drv)
        daemons.append(d)
        drivers.append(drv)

    async def one(d: TimedDaemon, delay_s: float) -> int:
        await asyncio.sleep(delay_s)
        return await d.run()

    window: list[float] = []
    gc_pauses: list[tuple[int, float]] = []  # (generation, seconds) in the window
    gc_t0 = [0.0]

    def on_gc(phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            gc_t0[0] = time.perf_counter()
        elif len(window) == 2:
            gc_pauses.append((info["generation"], time.perf_counter() - gc_t0[0]))

    gc.callbacks.append(on_gc)
    _watch_gc("worker")

    async def conductor() -> None:
        # the window opens WARMUP s after every daemon has run its first cycle (so
        # that connecting daemons do not count against the others) and lasts `seconds`
        await asyncio.gather(*(d.first_cycle.wait() for d in daemons))
        await asyncio.sleep(WARMUP_CYCLES)
        window.extend([time.monotonic(), time.process_time()])
        counts.append(troubles())
        io.extend([_write_bytes(), sends[0]])
        print("window", flush=True)
        if os.environ.get("FLEET_DEBUG"):  # a profiler attached from outside starts here
            print(f"window open at {time.strftime('%H:%M:%S')}", file=sys.stderr, flush=True)
        await asyncio.sleep(seconds)
        window.extend([time.monotonic(), time.process_time()])
        counts.append(troubles())
        io.extend([_write_bytes(), sends[0]])
        for d in daemons:
            d.request_stop()

    def troubles() -> tuple[int, int]:
        return (sum(d.loop.overruns for d in daemons),
                sum(d.loop.cycles - d.telemetry.complete_cycles for d in daemons))

    counts: list[tuple[int, int]] = []  # (overruns, incomplete) at window open, close
    io: list[int] = []  # (write_bytes, sends) at window open, then at close
    tasks = [one(d, o) for d, o in zip(daemons, offsets_s, strict=True)]
    rcs = await asyncio.gather(conductor(), *tasks, return_exceptions=True)
    late: list[float] = []
    for d in daemons:
        late.extend(d.times.lateness(d.running.cfg.real_period_s, since=window[0], until=window[2]))
    cycles = sum(1 for d in daemons for s in d.times.start if window[0] <= s < window[2])
    return {
        "late_s": late,
        # in the window (steady state); before it: the start-up burst, reported apart
        "overruns": counts[1][0] - counts[0][0],
        "start_overruns": counts[0][0],
        "cycles": cycles,
        "cpu": (window[3] - window[1]) / (window[2] - window[0]),
        # (a cycle under way at either end counts as started, not yet complete)
        "incomplete": max(0, counts[1][1] - counts[0][1]),
        "start_incomplete": counts[0][1],
        "leaked": sum(drv.leaked for drv in drivers),
        "own_s": mean([a - b for d in daemons
                       for a, b in zip(d.times.total, d.times.io, strict=True)]),
        "own_p99_s": percentile([a - b for d in daemons for a, b in
                                 zip(d.times.total, d.times.io, strict=True)], 0.99),
        "record_s": mean([x for d in daemons for x in d.times.record]),
        "telemetry_s": mean([x for d in daemons for x in d.times.telemetry]),
        "gc_gen2": sum(1 for g, _ in gc_pauses if g == 2),
        "gc_max_ms": max((p for _, p in gc_pauses), default=0.0) * 1e3,
        "gc_ms": sum(p for _, p in gc_pauses) * 1e3,
        "gc_counts": [sum(1 for g, _ in gc_pauses if g == k) for k in range(3)],
        "write_bytes": io[2] - io[0],
        "sends": io[3] - io[1],
        "failed": [repr(r) for r in rcs[1:] if r != 0] + (
            [repr(rcs[0])] if rcs[0] is not None else []),
    }


#: what FLEET_ABLATE (a comma-separated list) may take out of the daemons, to find
#: what a step's time goes to: four disk threads instead of `diskwriter.THREADS`, the
#: recorder, or the garbage-collection policy (CPython's own thresholds instead)
ABLATIONS = ("disk4", "norecorder", "nogc")


def ablations() -> set[str]:
    asked = {a for a in os.environ.get("FLEET_ABLATE", "").split(",") if a}
    if bad := asked - set(ABLATIONS):
        raise SystemExit(f"FLEET_ABLATE: unknown {sorted(bad)} (known: {', '.join(ABLATIONS)})")
    return asked


def _ablate(asked: set[str]) -> None:
    from compd.runtime import diskwriter, gcpolicy

    if "disk4" in asked:
        diskwriter.PROCESS_DISK.shutdown()
        diskwriter.PROCESS_DISK._threads = 4
    if "nogc" in asked:
        gcpolicy.PROCESS_GC.install = lambda: None  # type: ignore[method-assign]


def _worker_main(args: argparse.Namespace) -> None:
    from compd.faces.telemetry import configure_logging

    _ablate(ablations())
    spec = json.loads(Path(args.worker).read_text())
    with Path(spec["log"]).open("w") as log:
        configure_logging(json=True, level="info", stream=log)
        out = asyncio.run(_worker(spec["configs"], spec["offsets_s"], spec["seconds"]))
    print(json.dumps(out), flush=True)
    if os.environ.get("FLEET_DEBUG"):
        print({k: v for k, v in out.items() if k != "late_s"}, file=sys.stderr)


# -- the parent: one step of N machines --------------------------------------------------

@dataclass
class Step:
    n: int
    cycles: int
    late_p50_ms: float
    late_p99_ms: float
    late_max_ms: float
    #: in the measured window (steady state: what `holds` judges)
    overruns: int
    incomplete: int
    #: before the window: the start-up burst of every daemon connecting at once
    start_overruns: int
    start_incomplete: int
    leaked: int
    own_ms: float
    cpu_daemons: float  # CPU seconds per second, all workers
    cpu_sims: float
    rss_worker_mb: float
    failed: list[str]
    loadavg: float
    #: longest collection in the window (ms, any worker) and full collections in it
    gc_max_ms: float = math.nan
    gc_gen2: int = 0
    #: disk bytes written by the workers per cycle in the window; requests per cycle
    write_bytes_per_cycle: float = math.nan
    requests_per_cycle: float = math.nan

    @property
    def holds(self) -> bool:
        return (self.late_p99_ms < LIMIT_MS and self.overruns == 0 and not self.failed
                and self.incomplete <= 0.01 * max(1, self.cycles))


def start_farms(protocol: str, n: int, w: int, step_dir: Path
                ) -> tuple[list[subprocess.Popen[str]], list[dict[str, Any]]]:
    """`w` sim farm processes serving `n` simulated controllers between them, and
    the controllers' descriptions once every farm serves."""
    farms = [subprocess.Popen(
        [sys.executable, str(HERE), "--sim-farm", protocol,
         "--count", str(n // w + (k < n % w))],
        stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
        stderr=(step_dir / f"farm{k}.err").open("w"), text=True) for k in range(w)]
    descs: list[dict[str, Any]] = []
    try:
        for k, farm in enumerate(farms):
            line = farm.stdout.readline() if farm.stdout else ""
            if not line:
                rc = farm.wait()
                tail = "".join((step_dir / f"farm{k}.err").read_text().splitlines(True)[-5:])
                raise RuntimeError(f"a sim farm for {protocol} exited {rc}:\n{tail}")
            descs.extend(json.loads(line))
    except BaseException:
        for farm in farms:
            farm.kill()
            farm.wait()
        raise
    return farms, descs


def run_step(protocol: str, n: int, *, seconds: int, workers: int, aligned: bool,
             checkpoint_every: int, work: Path) -> Step:
    step_dir = work / f"{protocol}-{n}"
    step_dir.mkdir(parents=True)
    w = min(workers, n)
    farms, descs = start_farms(protocol, n, w, step_dir)
    procs: list[subprocess.Popen[str]] = []
    try:
        specs: list[dict[str, Any]] = [
            {"configs": [], "offsets_s": [], "seconds": seconds,
             "log": str(step_dir / f"worker{k}.log")} for k in range(w)]
        for i, desc in enumerate(descs):
            doc = config_doc(desc, state_dir=step_dir / f"state{i}",
                             checkpoint_every=checkpoint_every)
            if "norecorder" in ablations():
                doc["recorder"]["enabled"] = False
            path = write_config(doc, step_dir / f"machine{i}.toml")
            spec = specs[i % w]
            spec["configs"].append(str(path))
        for spec in specs:  # as `compd run DIR` starts its machines (phases spread)
            k = len(spec["configs"])
            spec["offsets_s"] = [0.0] * k if aligned else staggered_starts(k, 1.0)
        for k, spec in enumerate(specs):
            spec_path = step_dir / f"worker{k}.json"
            spec_path.write_text(json.dumps(spec))
            procs.append(subprocess.Popen(
                [sys.executable, str(HERE), "--worker", str(spec_path)],
                stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, text=True))
        # the farms' CPU over (about) the workers' measured window
        for p in procs:
            if p.stdout is None or p.stdout.readline().strip() != "window":
                raise RuntimeError(f"a worker exited {p.wait()} before its window")
        f0 = sum(cpu_s(f.pid) for f in farms)
        t0 = time.monotonic()
        time.sleep(max(1.0, seconds - 1.0))
        cpu_f = (sum(cpu_s(f.pid) for f in farms) - f0) / (time.monotonic() - t0)
        rss = max(rss_mb(p.pid) for p in procs)
        load = Path("/proc/loadavg").read_text().split()[0]
        results = []
        for p in procs:
            out, _ = p.communicate(timeout=seconds + 120)
            if p.returncode != 0 or not out.strip():
                raise RuntimeError(f"worker exited {p.returncode}")
            results.append(json.loads(out.strip().splitlines()[-1]))
        cpu_d = sum(r["cpu"] for r in results)
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
        stop_processes(farms)
    late = [x for r in results for x in r["late_s"]]
    cycles_in_window = max(1, sum(r["cycles"] for r in results))
    return Step(
        n=n, cycles=sum(r["cycles"] for r in results),
        late_p50_ms=percentile(late, 0.5) * 1e3, late_p99_ms=percentile(late, 0.99) * 1e3,
        late_max_ms=max(late, default=math.nan) * 1e3,
        overruns=sum(r["overruns"] for r in results),
        incomplete=sum(r["incomplete"] for r in results),
        start_overruns=sum(r["start_overruns"] for r in results),
        start_incomplete=sum(r["start_incomplete"] for r in results),
        leaked=sum(r["leaked"] for r in results),
        own_ms=mean([r["own_s"] for r in results]) * 1e3,
        cpu_daemons=cpu_d, cpu_sims=cpu_f, rss_worker_mb=rss,
        failed=[f for r in results for f in r["failed"]], loadavg=float(load),
        gc_max_ms=max(r["gc_max_ms"] for r in results),
        gc_gen2=sum(r["gc_gen2"] for r in results),
        write_bytes_per_cycle=sum(r["write_bytes"] for r in results) / cycles_in_window,
        requests_per_cycle=sum(r["sends"] for r in results) / cycles_in_window)


def print_step(protocol: str, s: Step) -> None:
    print(f"{protocol:7s}{s.n:6d}{s.cycles:8d}{s.late_p50_ms:9.2f}{s.late_p99_ms:9.2f}"
          f"{s.late_max_ms:9.2f}{s.overruns:8d}{s.incomplete:7d}{s.own_ms:8.3f}"
          f"{s.cpu_daemons:8.2f}{s.cpu_sims:8.2f}{s.rss_worker_mb:8.0f}{s.loadavg:6.1f}"
          f"{s.gc_max_ms:7.1f}{s.gc_gen2:4d}{s.write_bytes_per_cycle:8.0f}"
          f"{s.requests_per_cycle:6.2f}"
          f"  {'holds' if s.holds else 'FAILS'}"
          f"  start: {s.start_overruns} overruns, {s.start_incomplete} incomplete"
          f"{'  leaked=' + str(s.leaked) if s.leaked else ''}"
          f"{'  ' + '; '.join(s.failed)[:120] if s.failed else ''}", flush=True)


def search(protocol: str, args: argparse.Namespace, work: Path) -> tuple[Step, int, Step | None]:
    def step(n: int) -> Step:
        s = run_step(protocol, n, seconds=args.seconds, workers=args.workers[0],
                     aligned=args.aligned, checkpoint_every=args.checkpoint_every,
                     work=work)
        print_step(protocol, s)
        return s

    single = step(1)
    if args.sizes:
        held = [s for s in map(step, args.sizes) if s.holds]
        top = max(held, key=lambda s: s.n, default=None)
        return single, top.n if top else 0, top
    best = 0
    best_step: Step | None = None
    n = args.start
    fail: int | None = None
    while n <= args.max:
        s = step(n)
        if not s.holds:
            fail = n
            break
        best, best_step = n, s
        n *= 2
    if fail is not None and fail - best > 1:
        mid = (best + fail) // 2 if best else max(1, fail // 2)
        s = step(mid)
        if s.holds and mid > best:
            best, best_step = mid, s
    return single, best, best_step


def run_dir(args: argparse.Namespace) -> None:
    """`compd run DIR --workers W` at each N of --sizes, each W of --workers in turn."""
    print(f"compd run DIR --workers W at 1 Hz on {os.cpu_count()} CPUs, {args.farms} sim "
          f"farms, {args.seconds} s window, checkpoint every {args.checkpoint_every}, "
          f"event loop {os.environ.get('FLEET_LOOP', 'asyncio')}")
    fleet_run_dir.print_header()
    with tempfile.TemporaryDirectory(prefix="bench-daemon-fleet-") as tmp:
        for protocol in args.protocols:
            for n in args.sizes:
                for w in args.workers:
                    s = fleet_run_dir.run_step_run_dir(
                        protocol, n, w, seconds=args.seconds,
                        checkpoint_every=args.checkpoint_every, work=Path(tmp), here=HERE,
                        start_farms=lambda d, n=n, p=protocol: start_farms(p, n, args.farms, d))
                    fleet_run_dir.print_step(protocol, s)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--protocols", nargs="+", default=["modbus", "opcua"],
                        choices=["modbus", "opcua", "s7"])
    parser.add_argument("--seconds", type=int, default=20,
                        help="measured cycles (1 Hz) per machine per step")
    parser.add_argument("--start", type=int, default=32, help="first N after N = 1")
    parser.add_argument("--max", type=int, default=1024)
    parser.add_argument("--workers", type=int, nargs="+",
                        default=[len(os.sched_getaffinity(0))],
                        help="daemon worker processes (default: the CPUs); with --run-dir "
                             "compd run's --workers, each in turn")
    parser.add_argument("--run-dir", action="store_true",
                        help="measure `compd run DIR --workers W` itself at each --sizes")
    parser.add_argument("--farms", type=int, default=len(os.sched_getaffinity(0)),
                        help="with --run-dir: sim farm processes (default: the CPUs)")
    parser.add_argument("--pool", metavar="DIR", help=argparse.SUPPRESS)
    parser.add_argument("--pool-workers", type=int, default=1, help=argparse.SUPPRESS)
    parser.add_argument("--pool-out", help=argparse.SUPPRESS)
    parser.add_argument("--pool-worker", metavar="OUT", help=argparse.SUPPRESS)
    parser.add_argument("--checkpoint-every", type=int, default=20,
                        help="state.checkpoint_every (default 20, so that each daemon "
                             "checkpoints (fsync) once in a 20 s step: 3x the production "
                             "rate of 60; use 60 with --seconds 65 for the production rate)")
    parser.add_argument("--sizes", type=int, nargs="+", default=None,
                        help="run exactly these N (after N = 1) instead of the search; "
                             "with --run-dir the numbers of machines (default 2000)")
    parser.add_argument("--aligned", action="store_true",
                        help="start all daemons at the same instant (worst case)")
    parser.add_argument("--sim-farm", metavar="PROTOCOL", help=argparse.SUPPRESS)
    parser.add_argument("--count", type=int, default=1, help=argparse.SUPPRESS)
    parser.add_argument("--worker", metavar="SPEC", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.sim_farm:
        asyncio.run(_sim_farm(args.sim_farm, args.count))
        return
    if args.worker:
        _worker_main(args)
        return
    if args.pool_worker:
        sys.exit(fleet_run_dir.pool_worker_main(args.pool_worker))
    if args.pool:
        sys.exit(fleet_run_dir.pool_main(args.pool, args.pool_workers, args.pool_out, HERE))
    if args.run_dir:
        args.sizes = args.sizes or [2000]
        run_dir(args)
        return
    print(f"fleet at 1 Hz on {os.cpu_count()} CPUs, {args.workers[0]} daemon workers, "
          f"{args.seconds} s window per step, checkpoint every "
          f"{args.checkpoint_every}, phases "
          f"{'aligned' if args.aligned else 'spread over the period'}"
          f"{', without ' + ', '.join(sorted(ablations())) if ablations() else ''}")
    print(f"{'proto':7s}{'N':>6s}{'cycles':>8s}{'late50':>9s}{'late99':>9s}{'max':>9s}"
          f"{'overrun':>8s}{'incmpl':>7s}{'own ms':>8s}{'cpu dmn':>8s}{'cpu sim':>8s}"
          f"{'RSS MB':>8s}{'load':>6s}{'gc ms':>7s}{'gc2':>4s}{'B/cyc':>8s}{'req':>6s}\n"
          "(lateness ms over the window; cpu = CPU s per s; "
          "RSS of the largest worker; load = 1-min load average at the end of the window;\n"
          " overrun/incmpl in the window; start: before it, while the daemons started;\n"
          " gc ms = longest collection in the window, gc2 = full collections in it; "
          "B/cyc = disk bytes written per cycle; req = requests (socket sends) per cycle)")
    summary = []
    with tempfile.TemporaryDirectory(prefix="bench-daemon-fleet-") as tmp:
        for protocol in args.protocols:
            summary.append((protocol, *search(protocol, args, Path(tmp))))
    print("\nlargest N at 1 Hz with p99 lateness < 10 ms (peer: N = 1, same run)")
    for protocol, single, best, best_step in summary:
        if best_step is None:
            print(f"  {protocol:7s} none held (N = 1: p99 {single.late_p99_ms:.2f} ms)")
            continue
        print(f"  {protocol:7s} N = {best:4d}: p99 {best_step.late_p99_ms:.2f} ms vs "
              f"{single.late_p99_ms:.2f} ms for one machine "
              f"({best_step.late_p99_ms / single.late_p99_ms:.1f}x); daemons "
              f"{best_step.cpu_daemons * 100:.0f} % CPU + sims {best_step.cpu_sims * 100:.0f} %"
              f"; daemon CPU per machine {best_step.cpu_daemons / best * 1e3:.2f} ms/s")


if __name__ == "__main__":
    main()
