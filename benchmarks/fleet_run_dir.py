"""`bench_daemon_fleet.py --run-dir`: one step of N machines as `compd run DIR
--workers W` runs them.

Three roles, each a process started with this file's entry points through
bench_daemon_fleet.py:

- the pool (``--pool DIR --pool-workers W --pool-out OUT``): `compd run DIR
  --workers W` as `compd.commands.run.run_directory` runs it (the parent
  `compd.runtime.workers.WorkerPool`, or with W = 1 the one-process `Fleet`),
  except that each machine's daemon is a `TimedDaemon` on a `TimedDriver`
  (the timing hook around the unchanged daemon) and the workers are started
  as ``--pool-worker OUT`` instead of ``-m compd.runtime.worker_main``;
- a pool worker (``--pool-worker OUT``): `compd.runtime.worker_main.main` with
  the same timed daemons; at its end it writes each machine's cycle starts to
  OUT/times-PID.json;
- the step (`run_step_run_dir`, in the benchmark's process): writes the files,
  starts the pool with stderr to a log, waits until the log shows every
  machine's first cycle (``ready``), opens the window WARMUP s later (CPU of the pool's
  processes sampled at both ends, RSS at the end), stops the pool with
  SIGTERM and reads the lateness of every cycle in the window from the dumps
  (CLOCK_MONOTONIC is one clock for every process of the machine).

Each process of the pool also dumps its garbage collections (when each ended,
its generation and length: the longest in the window and the full ones are
printed) and its socket sends and cycles since its start (requests per cycle:
the drivers' requests, one send each for Modbus). CPU per cycle is the pool's
CPU seconds in the window over the machine-cycles that started in it: a step
that overruns (a loaded machine) still shows what one cycle costs.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from daemon_bench_common import (
    TimedDaemon,
    TimedDriver,
    config_doc,
    count_sends,
    cpu_s,
    percentile,
    rss_mb,
    stop_processes,
    watch_gc_pauses,
    write_config,
)

WARMUP_S = 3.0
#: the longest wait for every machine's first cycle before the window opens anyway
START_LIMIT_S = 300.0
_timed: list[TimedDaemon] = []
#: this process's socket sends and garbage collections (`_patch_fleet` starts both)
_counters: dict[str, Any] = {"sends": [0], "gc": []}


def _patch_fleet() -> None:
    """Every machine of `compd.runtime.fleet` a `TimedDaemon` on a `TimedDriver`."""
    import structlog

    from compd.runtime import fleet
    from compd.runtime.driver_setup import build_driver
    from compd.runtime.sdnotify import Notifier

    def timed_daemon(cfg: Any, **kwargs: Any) -> TimedDaemon:
        driver = kwargs.pop("driver", None) or build_driver(cfg)
        log = structlog.get_logger("compd").bind(machine=cfg.raw.machine.name)
        d = TimedDaemon(cfg, notifier=Notifier(None), serve_metrics=False, log=log,
                        driver=TimedDriver(driver), **kwargs)
        _timed.append(d)
        return d

    fleet.machine_daemon = timed_daemon  # type: ignore[assignment]
    _counters["sends"] = count_sends()
    _counters["gc"] = watch_gc_pauses()


def _dump(out: Path) -> None:
    doc = {d.running.cfg.raw.machine.name: {
        "start": d.times.start, "period_s": d.running.cfg.real_period_s,
        "overruns": d.loop.overruns, "cycles": d.loop.cycles,
        "incomplete": d.loop.cycles - d.telemetry.complete_cycles}
           for d in _timed}
    doc["_process"] = {"sends": _counters["sends"][0], "gc": _counters["gc"],
                       "cycles": sum(d.loop.cycles for d in _timed)}
    (out / f"times-{os.getpid()}.json").write_text(json.dumps(doc))


def pool_worker_main(out: str) -> int:
    from compd.runtime import worker_main

    _patch_fleet()
    _event_loop()
    try:
        return worker_main.main()
    finally:
        _dump(Path(out))


def _event_loop() -> None:
    """FLEET_LOOP=uvloop: the pool on uvloop's event loop instead of asyncio's (an
    experiment: uvloop is not one of compd's dependencies; install it in the venv)."""
    import asyncio

    name = os.environ.get("FLEET_LOOP", "asyncio")
    if name == "uvloop":
        import uvloop  # type: ignore[import-not-found,unused-ignore]

        asyncio.set_event_loop_policy(uvloop.EventLoopPolicy())
    elif name != "asyncio":
        raise SystemExit(f"FLEET_LOOP: unknown {name!r} (known: asyncio, uvloop)")


def pool_main(directory: str, workers: int, out: str, here: Path) -> int:
    import asyncio

    from compd.faces.telemetry import configure_logging
    from compd.runtime.fleet import Fleet, build_drivers, load_machines
    from compd.runtime.workers import WorkerPool

    configs = load_machines(Path(directory))
    configure_logging(json=True, level="info")
    _patch_fleet()
    _event_loop()
    if workers == 1:
        rc = asyncio.run(Fleet(configs, drivers=build_drivers(configs)).run())
        _dump(Path(out))
        return rc
    pool = WorkerPool(configs, workers, log_settings={"json": True, "level": "info"},
                      command=[sys.executable, str(here), "--pool-worker", out])
    return asyncio.run(pool.run())


def _children(pid: int) -> list[int]:
    try:
        text = Path(f"/proc/{pid}/task/{pid}/children").read_text()
    except OSError:
        return []
    return [int(x) for x in text.split()]


@dataclass
class RunDirStep:
    n: int
    workers: int
    cycles: int
    late_p50_ms: float
    late_p99_ms: float
    late_max_ms: float
    overruns: int
    cpu_pool: float  # CPU s per s: parent + workers
    cpu_sims: float
    rss_total_mb: float
    rss_max_mb: float
    start_s: float  # from the pool's start to every machine started
    loadavg: float
    failed: str = ""
    #: the pool's CPU per machine-cycle in the window (ms)
    cpu_ms_per_cycle: float = math.nan
    #: longest garbage collection in the window (ms, any process), full ones in it
    gc_max_ms: float = math.nan
    gc_gen2: int = 0
    #: socket sends per machine-cycle over the whole run
    requests_per_cycle: float = math.nan


def run_step_run_dir(protocol: str, n: int, workers: int, *, seconds: int,
                     checkpoint_every: int, work: Path, here: Path,
                     start_farms: Callable[[Path], tuple[list[subprocess.Popen[str]],
                                                         list[dict[str, Any]]]]
                     ) -> RunDirStep:
    step_dir = work / f"{protocol}-{n}-w{workers}"
    machines = step_dir / "machines.d"
    out = step_dir / "out"
    machines.mkdir(parents=True)
    out.mkdir()
    farms, descs = start_farms(step_dir)
    pool: subprocess.Popen[str] | None = None
    try:
        for i, desc in enumerate(descs):
            doc = config_doc(desc, state_dir=step_dir / f"state{i}",
                             checkpoint_every=checkpoint_every)
            doc["machine"]["name"] = f"m{i:05d}"
            write_config(doc, machines / f"m{i:05d}.toml")
        log = step_dir / "pool.log"
        t_start = time.monotonic()
        with log.open("w") as err:
            pool = subprocess.Popen(
                [sys.executable, str(here), "--pool", str(machines), "--pool-workers",
                 str(workers), "--pool-out", str(out)],
                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=err, text=True)
        started = 0
        while started < n:  # every machine ran its first cycle (its "ready" line)
            if pool.poll() is not None:
                raise RuntimeError(f"compd run exited {pool.returncode}: see {log}")
            if time.monotonic() - t_start > START_LIMIT_S:
                break  # an overloaded step: measured as it is, the count printed
            started = log.read_text(errors="replace").count('"event": "ready"')
            time.sleep(0.5)
        start_s = time.monotonic() - t_start
        time.sleep(WARMUP_S)
        procs = [pool.pid, *_children(pool.pid)]
        c0 = sum(cpu_s(p) for p in procs)
        f0 = sum(cpu_s(f.pid) for f in farms)
        t0 = time.monotonic()
        time.sleep(seconds)
        t1 = time.monotonic()
        cpu_pool = (sum(cpu_s(p) for p in procs) - c0) / (t1 - t0)
        cpu_sims = (sum(cpu_s(f.pid) for f in farms) - f0) / (t1 - t0)
        rss = [rss_mb(p) for p in procs]
        load = float(Path("/proc/loadavg").read_text().split()[0])
        pool.send_signal(signal.SIGTERM)
        rc = pool.wait(300)
    finally:
        if pool is not None and pool.poll() is None:
            pool.kill()
            pool.wait()
        stop_processes(farms)
    late: list[float] = []
    cycles = overruns = 0
    from daemon_bench_common import CycleTimes

    sends = all_cycles = 0
    gc_window: list[tuple[int, float]] = []
    for dump in out.glob("times-*.json"):
        doc = json.loads(dump.read_text())
        proc = doc.pop("_process", None)
        if proc is not None:
            sends += proc["sends"]
            all_cycles += proc["cycles"]
            gc_window.extend((g, p) for end, g, p in proc["gc"] if t0 <= end < t1)
        for m in doc.values():
            times = CycleTimes(start=m["start"])
            late.extend(times.lateness(m["period_s"], since=t0, until=t1))
            cycles += sum(1 for s in m["start"] if t0 <= s < t1)
            overruns += m["overruns"]
    return RunDirStep(
        n=n, workers=workers, cycles=cycles, late_p50_ms=percentile(late, 0.5) * 1e3,
        late_p99_ms=percentile(late, 0.99) * 1e3,
        late_max_ms=max(late, default=math.nan) * 1e3, overruns=overruns,
        cpu_pool=cpu_pool, cpu_sims=cpu_sims, rss_total_mb=sum(rss), rss_max_mb=max(rss),
        start_s=start_s, loadavg=load,
        cpu_ms_per_cycle=cpu_pool * (t1 - t0) / max(1, cycles) * 1e3,
        gc_max_ms=max((p for _, p in gc_window), default=0.0) * 1e3,
        gc_gen2=sum(1 for g, _ in gc_window if g == 2),
        requests_per_cycle=sends / max(1, all_cycles),
        failed=("" if rc == 0 else f"compd run exited {rc}") + (
            "" if started >= n else f" only {started} of {n} machines cycling"))


def print_header() -> None:
    print(f"{'proto':7s}{'N':>6s}{'W':>3s}{'cycles':>8s}{'late50':>9s}{'late99':>9s}"
          f"{'max':>9s}{'overrun':>8s}{'cpu cmp':>8s}{'cpu sim':>8s}{'RSS sum':>8s}"
          f"{'RSS max':>8s}{'start':>7s}{'load':>6s}{'ms/cyc':>7s}{'gc ms':>7s}{'gc2':>4s}"
          f"{'req':>6s}\n(lateness ms over the window; cpu = "
          "CPU s per s (parent + workers; the simulated controllers); RSS MB;\n start = s "
          "until every machine's first cycle; overrun: every cycle since the start;\n ms/cyc = "
          "the pool's CPU ms per machine-cycle in the window; gc ms = longest collection in "
          "the window, gc2 = full collections in it;\n req = requests (socket sends) per "
          "machine-cycle)")


def print_step(protocol: str, s: RunDirStep) -> None:
    print(f"{protocol:7s}{s.n:6d}{s.workers:3d}{s.cycles:8d}{s.late_p50_ms:9.2f}"
          f"{s.late_p99_ms:9.2f}{s.late_max_ms:9.2f}{s.overruns:8d}{s.cpu_pool:8.2f}"
          f"{s.cpu_sims:8.2f}{s.rss_total_mb:8.0f}{s.rss_max_mb:8.0f}{s.start_s:7.1f}"
          f"{s.loadavg:6.1f}{s.cpu_ms_per_cycle:7.3f}{s.gc_max_ms:7.1f}{s.gc_gen2:4d}"
          f"{s.requests_per_cycle:6.2f}{'  ' + s.failed if s.failed else ''}", flush=True)
