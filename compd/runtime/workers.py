"""`compd run DIR --workers N`: the machines of one directory over N processes.

The parent validates the whole directory first (`compd.runtime.fleet`'s
refusals: one bad file refuses the start, exit 78, nothing running), then
deals the machines round-robin in name order to N worker processes
(`compd.runtime.worker_main`, N at most the number of machines), each of
which runs its share as `compd run DIR` runs a directory in one process. So a
shop PC's cores serve one fleet, and each worker is a failure domain:

- a worker that ends (a crash, SIGKILL, the OOM killer) is logged
  (``worker_exited``) and started again with the same files after 1 s,
  doubling to 60 s (back to 1 s after a minute of running):
  ``worker_restarting``, ``compd_worker_restarts_total{worker}``. Only its
  machines stop meanwhile; their controllers see the heartbeat stop and hold
  the offset by their own fault policy, as when one `compd run FILE` dies.
  A restarted worker reads its files again, as a process that systemd
  restarts would (a file made bad since keeps that worker's machines down,
  exit 78 logged at each attempt, until it is mended);
- under systemd's watchdog (``WatchdogSec=``), a worker whose event loop stops
  answering (no ``WATCHDOG=1`` on its notify socket for that period) is killed
  (``worker_hung``) and restarted, as systemd would kill a single process
  whose loop hangs; without it, a worker silent for `WORKER_SILENT_S` is only
  logged (``worker_silent``): an overloaded loop is slow, not dead, and a
  restart would only add its start-up to the load;
- SIGTERM and the other stop signals are forwarded as SIGTERM to every worker
  (each machine applies its shutdown policy and writes its checkpoint); the
  parent exits 0 once every worker has, 70 when one ended otherwise; SIGHUP is
  forwarded to every worker that is ready (one still starting gets it when it
  is), which reloads each machine's own file;
- systemd: ``READY=1`` once every worker has said READY (all their machines'
  tasks started); ``WATCHDOG=1`` while the parent's loop runs (a hung worker is
  the parent's to kill, above); ``STATUS=`` "N machines in W workers (w
  running), M compensating". A worker that exits 78 before the pool is ready
  refuses the whole start (78), as a bad file does.

Each worker speaks sd_notify to a socket of its own in a private temporary
directory (mode 0700) and is stopped by the end of its stdin when the parent
goes. The one /metrics and status page: `compd.faces.worker_metrics`.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import re
import shutil
import signal
import socket
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import structlog

from compd.config.loader import LoadedConfig
from compd.faces.worker_metrics import PoolMetrics, WorkerView
from compd.runtime import signals
from compd.runtime.fleet import (
    BACKOFF_CAP_S,
    BACKOFF_INITIAL_S,
    BACKOFF_RESET_S,
    metrics_endpoint,
    metrics_limits,
)
from compd.runtime.sdnotify import Notifier, watchdog_interval_s
from compd.runtime.tasks import gather_with
from compd.sysexits import EX_CONFIG, EX_SOFTWARE

__all__ = ["WORKER_SILENT_S", "WorkerPool", "assign", "default_workers"]

#: without systemd's watchdog: a worker silent this long is logged, never killed
WORKER_SILENT_S = 60.0
#: the worker's entry point
WORKER_COMMAND: tuple[str, ...] = (sys.executable, "-m", "compd.runtime.worker_main")
_COMPENSATING = re.compile(r"(\d+) compensating")


def default_workers() -> int:
    """The cores this process may run on (its CPU affinity: systemd's CPUAffinity=,
    a container's cpuset)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def assign(names: Sequence[str], workers: int) -> list[list[str]]:
    """The machines, in name order, dealt round-robin to `workers` (at most one
    worker per machine): the same files go to the same worker at every start."""
    ordered = sorted(names)
    n = max(1, min(workers, len(ordered)))
    return [ordered[k::n] for k in range(n)]


@dataclass
class Worker:
    """One worker process's slot: its machines, its notify socket, its state."""

    index: int
    configs: list[LoadedConfig]
    sock: socket.socket
    path: str
    proc: asyncio.subprocess.Process | None = None
    #: READY=1 of the present process (its handlers installed, its machines started)
    ready: bool = False
    ever_ready: bool = False
    port: int | None = None
    last_ping: float = 0.0
    compensating: int = 0
    silent_logged: bool = False
    reload_pending: bool = False
    exit_codes: list[int] = field(default_factory=list)

    @property
    def machines(self) -> tuple[str, ...]:
        return tuple(c.raw.machine.name for c in self.configs)

    def view(self) -> WorkerView:
        paged = tuple(c.raw.machine.name for c in self.configs if c.raw.faces.http.enabled)
        return WorkerView(self.index, self.machines, self.port if self.ready else None, paged)


class WorkerPool:
    """The parent of `compd run DIR --workers N`: supervises the workers, serves
    the one endpoint, forwards the signals, speaks to systemd."""

    def __init__(self, configs: list[LoadedConfig], workers: int, *, dry_run: bool = False,
                 notifier: Notifier | None = None, log_settings: dict[str, Any] | None = None,
                 command: Sequence[str] = WORKER_COMMAND,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.configs = configs
        self.dry_run = dry_run
        self.notifier = notifier if notifier is not None else Notifier()
        self.log_settings = dict(log_settings or {})
        self.command = list(command)
        self.clock = clock
        self.log = structlog.get_logger("compd")
        self.stopping = asyncio.Event()
        self.ready = False
        self.rc = 0
        #: systemd's watchdog period for the parent: each worker's too (None: none)
        self.watchdog_s = watchdog_interval_s()
        self.metrics = PoolMetrics(self._views)
        self._tmp = tempfile.mkdtemp(prefix="compd-workers-")  # mode 0700
        by_name = {c.raw.machine.name: c for c in configs}
        self.workers: list[Worker] = []
        for k, names in enumerate(assign(list(by_name), workers)):
            path = str(Path(self._tmp) / f"notify-{k}")
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
            sock.bind(path)
            sock.setblocking(False)
            self.workers.append(Worker(k, [by_name[n] for n in names], sock, path))

    def close(self) -> None:
        """Close the notify sockets and remove their directory (`run` does, at its end)."""
        for w in self.workers:
            w.sock.close()
        shutil.rmtree(self._tmp, ignore_errors=True)

    def _views(self) -> list[WorkerView]:
        return [w.view() for w in self.workers]

    # -- requests ----------------------------------------------------------------------

    def request_stop(self, sig: signal.Signals | None = None) -> None:
        if sig is not None:
            level = "info" if sig in (signal.SIGTERM, signal.SIGINT) else "warning"
            getattr(self.log, level)("signal_received", signal=sig.name, action="stop")
        self.stopping.set()
        for w in self.workers:
            self._signal(w, signal.SIGTERM)

    def request_reload(self) -> None:
        for w in self.workers:
            if w.ready:
                self._signal(w, signal.SIGHUP)
            else:
                w.reload_pending = True

    def signal_ignored(self, sig: signal.Signals) -> None:
        self.log.warning("signal_ignored", signal=sig.name,
                         reason="SIGHUP reloads, SIGTERM stops compd cleanly")

    @staticmethod
    def _signal(w: Worker, sig: signal.Signals) -> None:
        if w.proc is not None and w.proc.returncode is None:
            with contextlib.suppress(ProcessLookupError):
                w.proc.send_signal(sig)

    # -- the workers' notify sockets -----------------------------------------------------

    def _on_datagram(self, w: Worker) -> None:
        while True:
            try:
                data = w.sock.recv(4096)
            except OSError:  # none left (BlockingIOError), or the socket closed
                return
            fields = dict(line.partition("=")[::2]
                          for line in data.decode("utf-8", "replace").splitlines())
            now = self.clock()
            if fields.get("READY") == "1":
                pid = fields.get("MAINPID")
                if w.proc is None or pid != str(w.proc.pid):
                    continue  # an earlier process's message
                port = fields.get("COMPD_METRICS_PORT")
                w.port = int(port) if port and port.isdigit() else None
                w.ready = w.ever_ready = True
                w.last_ping = now
                self.log.info("worker_ready", worker=w.index, pid=w.proc.pid,
                              machines=len(w.configs))
                if w.reload_pending:
                    w.reload_pending = False
                    self._signal(w, signal.SIGHUP)
            if fields.get("WATCHDOG") == "1":
                w.last_ping = now
                if w.silent_logged:
                    w.silent_logged = False
                    self.log.info("worker_answering", worker=w.index)
            status = fields.get("STATUS")
            if status is not None and (m := _COMPENSATING.search(status)):
                w.compensating = int(m.group(1))

    # -- running -------------------------------------------------------------------------

    def _spec(self, w: Worker, serve: bool) -> bytes:
        spec = {"index": w.index, "files": [str(c.path) for c in w.configs],
                "dry_run": self.dry_run, "serve": serve, "log": self.log_settings}
        return json.dumps(spec).encode() + b"\n"

    def _env(self, w: Worker) -> dict[str, str]:
        env = dict(os.environ)
        env["NOTIFY_SOCKET"] = w.path
        env.pop("WATCHDOG_PID", None)
        env.pop("WATCHDOG_USEC", None)
        if self.watchdog_s is not None:
            env["WATCHDOG_USEC"] = str(int(self.watchdog_s * 1e6))
        return env

    async def run(self) -> int:
        """Run every worker until SIGTERM (or `request_stop`); 0 when every worker
        stopped cleanly, 70 when one did not, 78 when a worker refused its files
        before the pool was ready."""
        loop = asyncio.get_running_loop()
        installed = signals.install(loop, stop=self.request_stop, reload=self.request_reload,
                                    ignored=self.signal_ignored)
        endpoint = metrics_endpoint(self.configs)
        if endpoint is not None:
            enabled = [c.raw.faces.http for c in self.configs if c.raw.faces.http.enabled]
            refresh = min(h.refresh_s for h in enabled) if enabled else None
            try:
                self.metrics.serve(endpoint[1], endpoint[0], refresh,
                                   metrics_limits(self.configs))
            except OSError as exc:
                self.log.error("metrics_unavailable", host=endpoint[0], port=endpoint[1],
                               error=str(exc))
        for w in self.workers:
            loop.add_reader(w.sock.fileno(), self._on_datagram, w)
        self.log.info("pool_starting", machines=len(self.configs), workers=len(self.workers),
                      dry_run=self.dry_run)
        tasks = [loop.create_task(self._supervise(w, endpoint is not None),
                                  name=f"compd-worker-{w.index}") for w in self.workers]
        try:
            await gather_with(tasks, loop.create_task(self._watch()))
        finally:
            self.notifier.stopping()
            self.metrics.stop()
            for w in self.workers:
                loop.remove_reader(w.sock.fileno())
            self.close()
            signals.remove(loop, installed)
        self.log.info("pool_stopped", workers=len(self.workers), rc=self.rc,
                      restarts={w.index: len(w.exit_codes) for w in self.workers
                                if w.exit_codes})
        return self.rc

    async def _spawn(self, w: Worker, serve: bool) -> asyncio.subprocess.Process:
        proc = await asyncio.create_subprocess_exec(
            *self.command, stdin=asyncio.subprocess.PIPE, env=self._env(w))
        w.proc = proc  # before its READY=1 can arrive
        if proc.stdin is not None:  # asked for above
            proc.stdin.write(self._spec(w, serve))
            with contextlib.suppress(ConnectionError):
                await proc.stdin.drain()
        return proc

    async def _supervise(self, w: Worker, serve: bool) -> None:
        """Run one worker; start it again after it ends, with backoff."""
        backoff = BACKOFF_INITIAL_S
        running = self.metrics.worker_running.labels(worker=str(w.index))
        restarts = self.metrics.worker_restarts.labels(worker=str(w.index))
        while not self.stopping.is_set():
            w.ready, w.port, w.compensating, w.silent_logged = False, None, 0, False
            started = self.clock()
            try:
                w.proc = await self._spawn(w, serve)
            except OSError as exc:
                self.log.error("worker_exited", worker=w.index, error=str(exc),
                               restart_in_s=backoff)
                rc = None
            else:
                if self.stopping.is_set():  # asked to stop while it was being started
                    self._signal(w, signal.SIGTERM)
                running.set(1)
                rc = await w.proc.wait()
                running.set(0)
                was_ready, w.ready, w.port = w.ready, False, None
                if w.proc.stdin is not None:
                    w.proc.stdin.close()
                if self.stopping.is_set():
                    # a worker stopped before it was ready had started no machine yet:
                    # SIGTERM's default action ended it, and that is clean
                    clean = rc == 0 or (rc == -signal.SIGTERM and not was_ready)
                    if rc == EX_CONFIG and not self.ready:
                        self.rc = EX_CONFIG  # it too refused its files at the start
                    elif not clean:
                        self.rc = self.rc or EX_SOFTWARE
                        self.log.error("worker_stopped", worker=w.index, rc=rc)
                    return
                w.exit_codes.append(rc)
                if rc == EX_CONFIG and not self.ready:
                    self.log.error("worker_refused_config", worker=w.index, rc=rc,
                                   action="stop")
                    self.rc = EX_CONFIG
                    self.request_stop()
                    return
                if self.clock() - started >= BACKOFF_RESET_S:
                    backoff = BACKOFF_INITIAL_S
                name = signal.Signals(-rc).name if rc < 0 else None
                self.log.error("worker_exited", worker=w.index, rc=rc, signal=name,
                               machines=list(w.machines), restart_in_s=backoff)
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self.stopping.wait(), backoff)
            backoff = min(backoff * 2.0, BACKOFF_CAP_S)
            if not self.stopping.is_set():
                restarts.inc()
                self.log.info("worker_restarting", worker=w.index,
                              restarts=len(w.exit_codes))

    def _check_silence(self, w: Worker, now: float) -> None:
        """A ready worker without WATCHDOG=1 for systemd's period is killed (restarted
        by its supervisor); without systemd's watchdog, one silent for long is logged."""
        if not w.ready or w.proc is None:
            return
        silent_s = now - w.last_ping
        if self.watchdog_s is not None and silent_s > self.watchdog_s:
            self.log.error("worker_hung", worker=w.index, silent_s=round(silent_s, 1),
                           action="kill")
            w.ready = False
            with contextlib.suppress(ProcessLookupError):
                w.proc.kill()
        elif self.watchdog_s is None and silent_s > WORKER_SILENT_S and not w.silent_logged:
            w.silent_logged = True
            self.log.warning("worker_silent", worker=w.index, silent_s=round(silent_s, 1))

    async def _watch(self) -> None:
        """READY once every worker was ready; WATCHDOG and STATUS; kill hung workers."""
        interval = self.notifier.watchdog_interval_s()
        every = interval / 2.0 if interval else 10.0
        last_beat = -float("inf")
        while True:
            now = self.clock()
            if not self.ready and all(w.ever_ready for w in self.workers):
                self.ready = True
                self.notifier.ready()
                self.log.info("pool_ready", workers=len(self.workers),
                              machines=len(self.configs))
            for w in self.workers:
                self._check_silence(w, now)
            if self.ready and now - last_beat >= every:
                last_beat = now
                up = sum(1 for w in self.workers if w.ready)
                self.notifier.watchdog()
                self.notifier.status(
                    f"{len(self.configs)} machines in {len(self.workers)} workers ({up} "
                    f"running), {sum(w.compensating for w in self.workers if w.ready)} "
                    "compensating")
            await asyncio.sleep(min(1.0, every))
