"""`compd run` with its OPC UA face ([faces.opcua]) under the shipped unit's
descriptor limit (``prlimit --nofile=1024:1024``, as ``LimitNOFILE=1024`` in
deploy/systemd/compd.service) while this script holds N idle TCP connections
to the face (2,000 by default) that never say a word: the cycle's lateness
p50/p99/max (from the daemon's recorder: each cycle's start against its
deadline), the checkpoints written, /metrics answering, and a controller
reconnect (this script's TCP relay between the daemon and the simulated
controller drops the link half-way through the flood), against the same
daemon over the same time before the flood (the peer, same run).

    .venv/bin/python benchmarks/bench_face_flood.py [--connections 2000] [--seconds 20]
        [--nofile 1024] [--time-scale 10]

The daemon's own log is searched for "Too many open files", asyncio's
"socket.accept() out of system resource" and "Traceback" (targets: none).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import math
import os
import resource
import shutil
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
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from daemon_bench_common import config_doc, percentile, start_sim, write_config  # noqa: E402

from drivers.sim.ports import free_tcp_port  # noqa: E402


class Relay:
    """A TCP relay to the simulated controller that can drop every link (`cut`)."""

    def __init__(self, host: str, port: int) -> None:
        self.host, self.port = host, port
        self.links: list[asyncio.StreamWriter] = []
        self.accepted: list[float] = []
        self.server: asyncio.Server | None = None

    async def start(self) -> int:
        self.server = await asyncio.start_server(self._link, "127.0.0.1", 0)
        return int(self.server.sockets[0].getsockname()[1])

    async def _link(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.accepted.append(time.monotonic())
        try:
            up_r, up_w = await asyncio.open_connection(self.host, self.port)
        except OSError:
            writer.close()
            return
        self.links += [writer, up_w]

        async def pipe(src: asyncio.StreamReader, dst: asyncio.StreamWriter) -> None:
            with contextlib.suppress(OSError):
                while data := await src.read(65536):
                    dst.write(data)
                    await dst.drain()
            dst.close()

        with contextlib.suppress(asyncio.CancelledError):  # the relay's end
            await asyncio.gather(pipe(reader, up_w), pipe(up_r, writer))

    def cut(self) -> None:
        for w in self.links:
            w.transport.abort()
        self.links.clear()

    async def stop(self) -> None:
        self.cut()
        if self.server is not None:
            self.server.close()
            await self.server.wait_closed()


@dataclass
class Phase:
    name: str
    start: float = 0.0  # wall clock (the recorder's wall_s)
    end: float = 0.0
    checkpoints: int = 0
    metrics_ok: int = 0
    metrics_tries: int = 0
    metrics_ms: list[float] = field(default_factory=list)
    max_fds: int = 0
    max_threads: int = 0
    extra: dict[str, Any] = field(default_factory=dict)


def _threads(pid: int) -> int:
    try:
        with open(f"/proc/{pid}/status", encoding="ascii") as f:
            return next(int(ln.split()[1]) for ln in f if ln.startswith("Threads:"))
    except (OSError, StopIteration, ValueError):
        return -1


def _fds(pid: int) -> int:
    try:
        return len(os.listdir(f"/proc/{pid}/fd"))
    except OSError:
        return -1


async def _watch(phase: Phase, pid: int, checkpoint: Path, metrics_url: str,
                 stop: asyncio.Event) -> None:
    """Count checkpoint writes (its mtime changing), ask /metrics twice a second,
    and note the daemon's open descriptors, until `stop`."""
    last = _mtime(checkpoint)
    next_scrape = 0.0
    while not stop.is_set():
        m = _mtime(checkpoint)
        if m != last:
            phase.checkpoints += 1
            last = m
        phase.max_fds = max(phase.max_fds, _fds(pid))
        phase.max_threads = max(phase.max_threads, _threads(pid))
        now = time.monotonic()
        if now >= next_scrape:
            next_scrape = now + 0.5
            phase.metrics_tries += 1
            t0 = time.perf_counter()
            try:
                body = await asyncio.to_thread(_get, metrics_url)
                if "compd_cycles_complete_total" in body:
                    phase.metrics_ok += 1
                    phase.metrics_ms.append((time.perf_counter() - t0) * 1e3)
                    phase.extra["metrics"] = body
            except OSError:
                pass
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(stop.wait(), 0.02)


def _mtime(path: Path) -> int:
    try:
        return os.stat(path).st_mtime_ns
    except OSError:
        return 0


def _get(url: str) -> str:
    with urllib.request.urlopen(url, timeout=2.0) as r:
        return str(r.read().decode())


def _spawn(cmd: list[str]) -> subprocess.Popen[str]:
    return subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)


def _metric(body: str, name: str) -> float:
    total = math.nan
    for line in body.splitlines():
        if line.startswith(name) and not line.startswith("#"):
            total = (0.0 if math.isnan(total) else total) + float(line.rsplit(" ", 1)[1])
    return total


def lateness(db: Path, time_scale: float, since: float, until: float) -> list[float]:
    """Each recorded cycle's start minus the nearest deadline (first cycle + k·period),
    in wall seconds, for the cycles recorded between wall times `since` and `until`.
    The recorder's ``mono_s`` is machine time on the monotonic clock (period 1 s)."""
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        rows = con.execute("SELECT mono_s, wall_s FROM samples ORDER BY seq").fetchall()
    finally:
        con.close()
    if len(rows) < 3:
        return []
    t0 = rows[0][0]
    out = []
    for s, wall in rows[1:-1]:
        if since <= wall < until:
            x = s - t0
            out.append((x - math.floor(x + 0.5)) / time_scale)
    return out


Held = list[tuple[asyncio.StreamReader, asyncio.StreamWriter]]


async def _hold(port: int, n: int) -> tuple[Held, int]:
    """Open `n` connections that never send a byte; (held streams, failed connects)."""
    held: Held = []
    failed = 0

    async def one() -> None:
        nonlocal failed
        try:
            held.append(await asyncio.wait_for(asyncio.open_connection("127.0.0.1", port),
                                               15.0))
        except (OSError, TimeoutError):
            failed += 1

    for i in range(0, n, 100):
        await asyncio.gather(*(one() for _ in range(min(100, n - i))))
    return held, failed


async def run(args: argparse.Namespace) -> int:
    tmp = Path(tempfile.mkdtemp(prefix="compd-face-flood-"))
    try:
        return await _run(args, tmp)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


async def _run(args: argparse.Namespace, tmp: Path) -> int:
    _soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))  # this script holds the flood
    sim = start_sim("modbus", speedup=args.time_scale)
    relay = Relay(*_host_port(sim.desc["endpoint"]))
    relay_port = await relay.start()
    face_port = free_tcp_port("127.0.0.1")
    metrics_port = free_tcp_port("127.0.0.1")
    desc = dict(sim.desc, endpoint=f"modbus://127.0.0.1:{relay_port}")
    doc = config_doc(desc, state_dir=tmp / "state", time_scale=args.time_scale,
                     checkpoint_every=args.checkpoint_every)
    doc["telemetry"]["metrics_port"] = metrics_port
    doc["faces"] = {"opcua": {"enabled": True, "port": face_port, "policy": "None",
                              "insecure": True}}
    cfg = write_config(doc, tmp / "compd.toml")
    period_s = 1.0 / args.time_scale
    cmd = ["prlimit", f"--nofile={args.nofile}:{args.nofile}", sys.executable, "-m", "compd",
           "run", str(cfg)]
    proc = _spawn(cmd)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(iter(proc.stderr.readline, "")),  # type: ignore[union-attr]
                              daemon=True)
    reader.start()
    checkpoint = tmp / "state" / "checkpoint.json"
    url = f"http://127.0.0.1:{metrics_port}/metrics"
    phases = [Phase("before (peer)"), Phase(f"{args.connections} idle connections")]
    held: Held = []
    try:
        for _ in range(3000):
            if any("opcua_face_started" in ln for ln in lines) or proc.poll() is not None:
                break
            await asyncio.sleep(0.02)
        if proc.poll() is not None:
            print("".join(lines)[-3000:], file=sys.stderr)
            return 1
        await asyncio.sleep(2.0)  # settle
        for i, phase in enumerate(phases):
            stop = asyncio.Event()
            phase.start = time.time()
            opened = time.monotonic()
            watcher = asyncio.create_task(_watch(phase, proc.pid, checkpoint, url, stop))
            if i == 1:
                held, failed = await _hold(face_port, args.connections)
                await asyncio.sleep(0.5)  # the face closes what is over its cap at once
                phase.extra["held"] = sum(not r.at_eof() for r, _ in held)
                phase.extra["connect_failed"] = failed
                phase.extra["opened_s"] = time.monotonic() - opened
            await asyncio.sleep(args.seconds / 2)
            before_cut = len(relay.accepted)
            cut_at = time.monotonic()
            connected_before = sum('"controller_reconnected"' in ln for ln in lines)
            relay.cut()  # the controller's link drops: the daemon must reconnect
            await asyncio.sleep(args.seconds / 2)
            back = [t for t in relay.accepted[before_cut:] if t >= cut_at]
            phase.extra["reconnect_s"] = (back[0] - cut_at) if back else math.nan
            phase.extra["reconnected"] = sum('"controller_reconnected"' in ln
                                             for ln in lines) > connected_before
            if i == 1:
                phase.extra["closed_by_face"] = sum(r.at_eof() for r, _ in held)
            stop.set()
            await watcher
            phase.end = time.time()
            for _, w in held:
                w.close()
            held = []
    finally:
        for _, w in held:
            w.close()
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        try:
            rc = proc.wait(60.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            rc = proc.wait()
        reader.join(5.0)
        await relay.stop()
        sim.stop()
    text = "".join(lines)
    db = tmp / "state" / "samples.sqlite"
    print(f"compd run under prlimit --nofile={args.nofile}:{args.nofile} (the unit's "
          f"LimitNOFILE), period {period_s * 1e3:.0f} ms, checkpoint every "
          f"{args.checkpoint_every} cycles, {args.seconds:.0f} s per phase; exit {rc}")
    print(f"{'phase':28s}{'cycles':>8s}{'late p50':>10s}{'p99':>8s}{'max':>8s}"
          f"{'ckpts':>7s}{'/metrics ok':>13s}{'max fds':>9s}{'threads':>9s}{'reconnect':>11s}")
    for phase in phases:
        late = lateness(db, args.time_scale, phase.start, phase.end)
        ok = f"{phase.metrics_ok}/{phase.metrics_tries}"
        rec = phase.extra.get("reconnect_s", math.nan)
        print(f"{phase.name:28s}{len(late):8d}{percentile(late, 0.5) * 1e3:8.2f}ms"
              f"{percentile(late, 0.99) * 1e3:6.2f}ms{max(late, default=math.nan) * 1e3:6.1f}ms"
              f"{phase.checkpoints:7d}{ok:>13s}{phase.max_fds:9d}{phase.max_threads:9d}"
              f"{rec:9.2f} s{'' if phase.extra.get('reconnected') else ' (none)'}")
    flood = phases[1]
    body = flood.extra.get("metrics", "")
    refused = "compd_opcua_face_connections_refused_total{reason="
    limit_n = _metric(body, refused + '"limit"}')
    timeout_n = _metric(body, refused + '"handshake_timeout"}')
    lines_n = text.count('"opcua_connection_refused"')
    cap = _metric(body, "compd_opcua_face_connection_limit")
    print(f"flood: {flood.extra.get('held', 0)} open on this side 0.5 s after the connect "
          f"burst (the face holds at most its limit; the rest wait in the kernel's queues), "
          f"{flood.extra.get('connect_failed', 0)} connects failed, "
          f"{flood.extra.get('closed_by_face', 0)} closed by the face by the end; "
          f"refused (metrics): limit {limit_n:.0f}, handshake_timeout {timeout_n:.0f}; "
          f"limit {cap:.0f}; /metrics "
          f"p99 {percentile(flood.metrics_ms, 0.99):.1f} ms (before: "
          f"{percentile(phases[0].metrics_ms, 0.99):.1f} ms)")
    bad = {s: text.count(s) for s in ("Too many open files", "out of system resource",
                                      "Traceback", "checkpoint_failed")}
    print("daemon log: " + ", ".join(f"{k!r} x{v}" for k, v in bad.items())
          + f"; opcua_connection_refused lines {lines_n}"
          + f", summaries {text.count('opcua_connection_refused_summary')}")
    return 0 if rc == 0 and not any(bad.values()) else 1


def _host_port(endpoint: str) -> tuple[str, int]:
    host, _, port = endpoint.split("://", 1)[1].rpartition(":")
    return host.strip("[]"), int(port)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--connections", type=int, default=2000)
    p.add_argument("--seconds", type=float, default=20.0, help="per phase")
    p.add_argument("--nofile", type=int, default=1024)
    p.add_argument("--time-scale", type=float, default=10.0,
                   help="machine seconds per wall second (period 1 s machine time)")
    p.add_argument("--checkpoint-every", type=int, default=10)
    return asyncio.run(run(p.parse_args()))


if __name__ == "__main__":
    sys.exit(main())
