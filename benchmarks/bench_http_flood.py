"""The HTTP faces under a connection flood, with the shipped unit's limits.

One `compd run` process (/metrics and the status page on, `[faces.http]`)
against a simulated Modbus machine (`compd sim --speedup`, 10 Hz real by
default), started under the limits of deploy/systemd/compd.service:
``LimitNOFILE=1024`` (prlimit) and
``TasksMax=64`` (a pids cgroup whose pids.max is 64, when this process may
create one: root with a writable /sys/fs/cgroup/pids or a cgroup2 tree with
the pids controller; otherwise threads are only counted). Three phases of
`--seconds` each, in one run:

- peer: no flood (the same daemon, the same minutes);
- slowloris: `--slowloris` sockets (800) that each send a partial request head
  and then one byte every `--trickle-s` seconds, reconnecting when closed;
- idle: `--idle` connections (2,000) that send nothing, reconnecting when closed.

The floods run in child processes (this file with ``--child``). Per phase:
cycle lateness (cycle start - its deadline, from the recorder's ``mono_s``,
in real ms: p50, p99, max) and overruns (``compd_overruns_total``), the most
threads (/proc/PID/task) and descriptors (/proc/PID/fd) seen, checkpoints
written (the checkpoint file replaced; expected: cycles / checkpoint_every)
and failed, /metrics scraped every 2 s (answered / asked, median and worst
seconds), `compd health --url` (exit status, seconds), a SIGHUP reload
(``reload_succeeded`` or ``reload_failed``), the connections the server
closed (client side); at the end the tracebacks in the daemon's stderr and
the cgroup's refused forks (pids.events max).

Run:  .venv/bin/python benchmarks/bench_http_flood.py [--seconds 30] [--slowloris 800]
      [--idle 2000] [--rate 10] [--also REV]
(about 2 minutes with the defaults).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import resource
import signal
import sqlite3
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from dataclasses import dataclass, field
from pathlib import Path

from daemon_bench_common import config_doc, cpu_s, percentile, start_sim, write_config

ROOT = Path(__file__).resolve().parent.parent
NOFILE = 1024
TASKS_MAX = 64
CHECKPOINT_EVERY = 20


# -- the flood (child processes) ------------------------------------------------------------

async def _client(port: int, trickle_s: float | None, stats: dict[str, int],
                  stop: asyncio.Event) -> None:
    """One socket kept open: a partial head and a byte every `trickle_s` (slowloris),
    or nothing at all (`trickle_s` None); reconnects when the server closes it."""
    while not stop.is_set():
        try:
            reader, writer = await asyncio.open_connection("127.0.0.1", port)
        except OSError:
            stats["connect_failed"] += 1
            await asyncio.sleep(0.5)
            continue
        stats["connects"] += 1
        try:
            if trickle_s is not None:
                writer.write(b"GET /metrics HTTP/1.1\r\nHost: compd\r\n")
            while not stop.is_set():
                try:
                    data = await asyncio.wait_for(reader.read(4096), trickle_s or 3600.0)
                except TimeoutError:
                    writer.write(b"X")  # one more byte of a header that never ends
                    await writer.drain()
                    continue
                if not data:
                    stats["closed_by_server"] += 1
                    break
        except OSError:
            stats["closed_by_server"] += 1
        finally:
            writer.close()
            with contextlib.suppress(OSError):
                await writer.wait_closed()


async def _flood(port: int, count: int, trickle_s: float | None) -> dict[str, int]:
    stats = {"connects": 0, "closed_by_server": 0, "connect_failed": 0}
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    loop.add_signal_handler(signal.SIGTERM, stop.set)
    tasks = [loop.create_task(_client(port, trickle_s, stats, stop)) for _ in range(count)]
    await stop.wait()
    for t in tasks:
        t.cancel()
    await asyncio.gather(*tasks, return_exceptions=True)
    return stats


def child(kind: str, port: int, count: int, trickle_s: float) -> None:
    _, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))
    stats = asyncio.run(_flood(port, count, trickle_s if kind == "slowloris" else None))
    print(json.dumps(stats), flush=True)


# -- the daemon under the unit's limits -----------------------------------------------------

def _pids_cgroup() -> Path | None:
    """A new pids cgroup with pids.max = TASKS_MAX, None when we may not make one."""
    name = f"compd-bench-http-{os.getpid()}"
    for base in (Path("/sys/fs/cgroup/pids"), Path("/sys/fs/cgroup/unified"),
                 Path("/sys/fs/cgroup")):
        try:
            if (base / "cgroup.controllers").exists() and \
                    "pids" not in (base / "cgroup.controllers").read_text().split():
                continue
            group = base / name
            group.mkdir()
            if not (group / "pids.max").exists():
                group.rmdir()
                continue
            (group / "pids.max").write_text(str(TASKS_MAX))
            return group
        except OSError:
            continue
    return None


def _under_limits(command: list[str], group: Path | None) -> list[str]:
    """`command` with NOFILE set by prlimit, in `group` (joined by the shell that execs
    it, so that every thread the daemon starts counts against pids.max)."""
    limited = ["prlimit", f"--nofile={NOFILE}:{NOFILE}", *command]
    if group is None:
        return limited
    return ["sh", "-c", 'echo $$ > "$0" && exec "$@"', str(group / "cgroup.procs"),
            *limited]


def _count(path: str) -> int:
    try:
        return len(os.listdir(path))
    except OSError:
        return -1


@dataclass
class Phase:
    name: str
    start_wall: float = 0.0
    end_wall: float = 0.0
    threads_max: int = 0
    fds_max: int = 0
    checkpoints: int = 0
    scrapes: list[float | None] = field(default_factory=list)
    health: list[tuple[int, float]] = field(default_factory=list)
    reload: str = "-"
    overruns: float = 0.0
    client: dict[str, int] = field(default_factory=dict)
    lateness_ms: list[float] = field(default_factory=list)
    cpu_s: float = 0.0
    seconds: float = 0.0


class Sampler(threading.Thread):
    """Threads, descriptors and checkpoint replacements of the daemon, every 50 ms."""

    def __init__(self, pid: int, checkpoint: Path) -> None:
        super().__init__(daemon=True)
        self.pid, self.checkpoint = pid, checkpoint
        self.phase: Phase | None = None
        self.done = threading.Event()

    def run(self) -> None:
        last: tuple[int, int] | None = None
        while not self.done.wait(0.05):
            phase = self.phase
            try:
                st = self.checkpoint.stat()
                now: tuple[int, int] | None = (st.st_ino, st.st_mtime_ns)
            except OSError:
                now = None
            if phase is None:
                last = now
                continue
            phase.threads_max = max(phase.threads_max, _count(f"/proc/{self.pid}/task"))
            phase.fds_max = max(phase.fds_max, _count(f"/proc/{self.pid}/fd"))
            if now is not None and now != last:
                phase.checkpoints += 1
            last = now


#: why scrapes failed (shown in the report)
SCRAPE_ERRORS: list[str] = []


def _scrape(url: str) -> tuple[float | None, str]:
    t0 = time.monotonic()
    try:
        with urllib.request.urlopen(url, timeout=10.0) as resp:
            body = resp.read().decode()
        return time.monotonic() - t0, body
    except OSError as exc:
        SCRAPE_ERRORS.append(f"{type(exc).__name__}: {exc}")
        return None, ""


def _metric(body: str, name: str) -> float:
    for line in body.splitlines():
        if line.startswith(name + " "):
            return float(line.split()[1])
    return float("nan")


def _health(url: str) -> tuple[int, float]:
    t0 = time.monotonic()
    rc = subprocess.run([sys.executable, "-m", "compd", "health", "--url", url,
                         "--timeout-s", "5"], stdout=subprocess.DEVNULL,
                        stderr=subprocess.DEVNULL, cwd=str(ROOT), check=False).returncode
    return rc, time.monotonic() - t0


def _reloads(log: Path) -> list[str]:
    out = []
    for line in log.read_text(errors="replace").splitlines():
        for event in ("reload_succeeded", "reload_failed"):
            if f'"{event}"' in line:
                out.append(event if event == "reload_succeeded"
                           else f"reload_failed ({json.loads(line).get('reason')})")
    return out


def run_phase(phase: Phase, args: argparse.Namespace, port: int, proc: subprocess.Popen[bytes],
              sampler: Sampler, log: Path) -> None:
    url = f"http://127.0.0.1:{port}/metrics"
    flood: subprocess.Popen[str] | None = None
    if phase.name != "peer":
        count = args.slowloris if phase.name == "slowloris" else args.idle
        flood = subprocess.Popen([sys.executable, __file__, "--child", phase.name,
                                  "--port", str(port), "--count", str(count),
                                  "--trickle-s", str(args.trickle_s)],
                                 stdout=subprocess.PIPE, text=True)
    _, body = _scrape(url)
    overruns0 = _metric(body, "compd_overruns_total")
    reloads0 = len(_reloads(log))
    phase.start_wall = time.time()
    sampler.phase = phase
    t0 = time.monotonic()
    cpu0 = cpu_s(proc.pid)
    hup_at, health_at = args.seconds / 2, (args.seconds / 3, 2 * args.seconds / 3)
    hup_sent, health_done = False, 0
    while (elapsed := time.monotonic() - t0) < args.seconds:
        latency, body = _scrape(url)
        phase.scrapes.append(latency)
        if health_done < len(health_at) and elapsed >= health_at[health_done]:
            phase.health.append(_health(url))
            health_done += 1
        if not hup_sent and elapsed >= hup_at:
            proc.send_signal(signal.SIGHUP)
            hup_sent = True
        time.sleep(max(0.0, 2.0 - (time.monotonic() - t0 - elapsed)))
    sampler.phase = None
    phase.end_wall = time.time()
    phase.cpu_s = cpu_s(proc.pid) - cpu0
    phase.seconds = time.monotonic() - t0
    if flood is not None:
        flood.send_signal(signal.SIGTERM)
        out, _ = flood.communicate(timeout=60)
        phase.client = json.loads(out.strip().splitlines()[-1]) if out.strip() else {}
    _, body = _scrape(url)
    phase.overruns = _metric(body, "compd_overruns_total") - overruns0
    got = _reloads(log)[reloads0:]
    phase.reload = ", ".join(got) if got else "no answer"


def lateness(recorder: Path, phases: list[Phase], period_s: float, time_scale: float) -> None:
    """Cycle start - its deadline, real ms, per phase (the grid: the first row's time
    + k periods, machine seconds, as the daemon's schedule keeps it)."""
    with contextlib.closing(sqlite3.connect(f"file:{recorder}?mode=ro", uri=True)) as db:
        rows = db.execute("SELECT mono_s, wall_s FROM samples ORDER BY seq").fetchall()
    if not rows:
        return
    m0 = rows[0][0]
    for mono, wall in rows[1:-1]:
        x = mono - m0
        late_ms = (x - period_s * round(x / period_s)) / time_scale * 1000.0
        for p in phases:
            if p.start_wall <= wall < p.end_wall:
                p.lateness_ms.append(late_ms)


def _fmt_s(values: list[float | None]) -> str:
    ok = sorted(v for v in values if v is not None)
    if not ok:
        return f"0/{len(values)} answered"
    return (f"{len(ok)}/{len(values)} answered, median {percentile(ok, 0.5):.3f} s, "
            f"worst {ok[-1]:.3f} s")


def report(phases: list[Phase], args: argparse.Namespace, group: Path | None,
           tracebacks: int, cycles_per_checkpoint: float) -> None:
    limit = f"pids cgroup pids.max={TASKS_MAX}" if group is not None else \
        "not enforced (no pids cgroup), threads counted"
    print(f"compd run, Modbus sim at {args.rate:g} Hz real; LimitNOFILE={NOFILE}, "
          f"TasksMax: {limit}; {args.seconds:g} s per phase")
    peer = phases[0]
    for p in phases:
        lat = p.lateness_ms
        p99 = percentile(lat, 0.99)
        print(f"\n[{p.name}]" + (f" {p.client}" if p.client else " (no flood)"))
        print(f"  cycle lateness: p50 {percentile(lat, 0.5):.2f} ms, p99 {p99:.2f} ms, "
              f"max {max(lat, default=float('nan')):.2f} ms over {len(lat)} cycles; "
              f"overruns {p.overruns:g}"
              + ("" if p is peer else
                 f"; p99 / peer's {p99 / percentile(peer.lateness_ms, 0.99):.2f}"))
        expected = len(lat) / cycles_per_checkpoint
        print(f"  daemon CPU {100 * p.cpu_s / p.seconds:.0f} % of a core; "
              f"threads max {p.threads_max} (peer {peer.threads_max}), descriptors max "
              f"{p.fds_max}; checkpoints written {p.checkpoints} (expected ~{expected:.0f})")
        print(f"  /metrics every 2 s: {_fmt_s(p.scrapes)}")
        print("  compd health --url: " + ", ".join(f"exit {rc} in {s:.2f} s"
                                                   for rc, s in p.health))
        print(f"  SIGHUP: {p.reload}")
    refused = "-"
    if group is not None:
        with contextlib.suppress(OSError):
            refused = (group / "pids.events").read_text().split()[-1]
    if SCRAPE_ERRORS:
        print(f"\nscrapes that failed: {sorted(set(SCRAPE_ERRORS))}")
    print(f"\ntracebacks in the daemon's stderr: {tracebacks}; forks refused by pids.max: "
          f"{refused}")


def measure(root: Path, label: str, args: argparse.Namespace) -> None:
    """The three phases against the daemon whose code is in `root`; prints the figures."""
    from compd.config.loader import load_config
    from compd.runtime.startup import checkpoint_path
    from drivers.sim.ports import free_tcp_port

    sim = start_sim("modbus", speedup=args.rate)
    group = _pids_cgroup()
    proc: subprocess.Popen[bytes] | None = None
    SCRAPE_ERRORS.clear()
    try:
        with tempfile.TemporaryDirectory(prefix="compd-bench-http-") as tmp_name:
            tmp = Path(tmp_name)
            port = free_tcp_port("127.0.0.1")
            doc = config_doc(sim.desc, state_dir=tmp / "state", time_scale=args.rate,
                             checkpoint_every=CHECKPOINT_EVERY)
            doc["telemetry"].update(metrics_port=port)
            doc["faces"] = {"http": {"enabled": True}}
            config = write_config(doc, tmp / "compd.toml")
            cfg = load_config(config)
            log = tmp / "daemon.log"
            env = {**os.environ, "PYTHONPATH": str(root)}
            env.pop("NOTIFY_SOCKET", None)
            with log.open("wb") as f:
                proc = subprocess.Popen(
                    _under_limits([sys.executable, "-m", "compd", "run", str(config)], group),
                    stdout=subprocess.DEVNULL, stderr=f, env=env, cwd=str(root))
            url = f"http://127.0.0.1:{port}/metrics"
            give_up = time.monotonic() + 60.0
            while not _metric(_scrape(url)[1], "compd_cycles_complete_total") >= 20:  # NaN
                if time.monotonic() > give_up or proc.poll() is not None:
                    raise SystemExit(f"the daemon did not start; see {log}")
                time.sleep(0.2)
            SCRAPE_ERRORS.clear()  # refused before the daemon listened
            sampler = Sampler(proc.pid, checkpoint_path(cfg))
            sampler.start()
            phases = [Phase("peer"), Phase("slowloris"), Phase("idle")]
            for phase in phases:
                run_phase(phase, args, port, proc, sampler, log)
            sampler.done.set()
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(60)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            assert cfg.recorder_path is not None
            lateness(cfg.recorder_path, phases, cfg.raw.machine.period_s, args.rate)
            tracebacks = log.read_text(errors="replace").count("Traceback")
            print(f"== {label}")
            report(phases, args, group, tracebacks, CHECKPOINT_EVERY)
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()
        sim.stop()
        if group is not None:
            with contextlib.suppress(OSError):
                group.rmdir()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=30.0, help="per phase")
    ap.add_argument("--slowloris", type=int, default=800)
    ap.add_argument("--idle", type=int, default=2000)
    ap.add_argument("--trickle-s", type=float, default=3.0)
    ap.add_argument("--rate", type=float, default=10.0, help="cycles per real second")
    ap.add_argument("--also", metavar="REV",
                    help="then the same against the daemon of git revision REV (e.g. the "
                         "commit before the bounded server), extracted with git archive")
    ap.add_argument("--child", choices=("slowloris", "idle"), help=argparse.SUPPRESS)
    ap.add_argument("--port", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--count", type=int, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(args.child, args.port, args.count, args.trickle_s)
        return
    measure(ROOT, "this tree", args)
    if args.also:
        with tempfile.TemporaryDirectory(prefix="compd-bench-rev-") as other:
            archive = subprocess.run(["git", "-C", str(ROOT), "archive", args.also],
                                     capture_output=True, check=False)
            if archive.returncode != 0:
                raise SystemExit(f"git archive {args.also}: {archive.stderr.decode().strip()}")
            subprocess.run(["tar", "-x", "-C", other], input=archive.stdout, check=True)
            print()
            measure(Path(other), f"git revision {args.also}", args)


if __name__ == "__main__":
    main()
