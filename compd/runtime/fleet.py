"""Several machines in one process: `compd run DIR` (every ``*.toml`` in DIR, sorted).

Each machine is its own failure domain: its own `Daemon` (driver, state
directory and lock, recorder, checkpoint, metrics registry) run as one asyncio
task of the one event loop. A controller's fault or slow link only delays its
own task: every driver call has its timeout, and blocking libraries run in
their driver's own worker thread (`drivers.io_thread`).

Start: every file is loaded and validated before anything runs; one bad file
refuses the whole start (`ConfigError` naming each bad file, exit 78), so that
nothing runs half-configured. So do two files with the same ``[machine] name``
(the metrics label, the log key) or the same state directory (one lock, one
checkpoint per machine), and two different metrics ports (one endpoint per
process: the files that set ``[telemetry] metrics_port`` must agree).

Start: the machines start one after the other, at least 10 ms apart, and
their cycles fall evenly over the (shortest) period (`staggered_starts`):
500 machines at 1 Hz are all running after about 7 s, and no two share a
deadline.

Running: a daemon task that ends by an exception is logged
(``machine_crashed``) and started again, with a fresh driver, after a backoff
(1 s doubling to 60 s, back to 1 s after a minute of running); the others are
untouched; so is one whose cycle broke (its loop returned EX_SOFTWARE after
its shutdown policy and checkpoint). It starts again on the config it ran (the
last one a SIGHUP reload swapped in), its model state restored from its
checkpoint as at any start. SIGTERM/SIGINT, and every other signal
whose default would end the process (`compd.runtime.signals`), stop every
machine (each applies its shutdown policy and writes its checkpoint), SIGHUP
reloads each machine's own file; SIGUSR1/2 and SIGXFSZ are logged and ignored.
With ``[faces.http]`` in any file, the one endpoint also answers the operator
page and /status.json, one section per machine (`compd.faces.status_http`).
Logging follows the first file's ``[telemetry]``; each line carries
``machine``.
"""

from __future__ import annotations

import asyncio
import contextlib
import signal
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import structlog

from compd.config.loader import LoadedConfig, load_config
from compd.config.overlaps import check_shared_controllers
from compd.core.schedule import staggered_starts
from compd.errors import ConfigError
from compd.faces.fleet_metrics import FleetMetrics
from compd.faces.http_server import HttpLimits, limits_from
from compd.faces.telemetry import Metrics, WSGIApp
from compd.runtime import signals
from compd.runtime.daemon import Daemon
from compd.runtime.heap import pin_mmap_threshold
from compd.runtime.sdnotify import Notifier
from compd.runtime.tasks import gather_with
from drivers.base import Driver

__all__ = ["Fleet", "build_drivers", "load_machines", "machine_daemon"]

BACKOFF_INITIAL_S = 1.0
BACKOFF_CAP_S = 60.0
#: a daemon that ran this long before crashing starts again after the initial backoff
BACKOFF_RESET_S = 60.0


def load_machines(directory: Path) -> list[LoadedConfig]:
    """Every ``*.toml`` in `directory` (sorted), validated; ConfigError names each bad file."""
    files = sorted(p for p in directory.glob("*.toml") if p.is_file())
    if not files:
        raise ConfigError("", f"{directory}: no *.toml machine configs in the directory")
    loaded: list[LoadedConfig] = []
    bad: list[str] = []
    for path in files:
        try:
            loaded.append(load_config(path))
        except ConfigError as exc:
            bad.append(f"{path}: {exc}")
    if bad:
        raise ConfigError("", "; ".join(bad))
    _refuse_shared(loaded)
    check_shared_controllers(loaded)
    return loaded


def build_drivers(configs: list[LoadedConfig]) -> dict[str, Driver]:
    """Each machine's driver, constructed (not connected): a refusal names its file."""
    from compd.runtime.driver_setup import build_driver

    drivers: dict[str, Driver] = {}
    for cfg in configs:
        try:
            drivers[cfg.raw.machine.name] = build_driver(cfg)
        except ConfigError as exc:
            raise ConfigError("", f"{cfg.path}: {exc}") from None
    return drivers


def _refuse_shared(configs: list[LoadedConfig]) -> None:
    names: dict[str, Path] = {}
    dirs: dict[Path, Path] = {}
    ports: dict[tuple[str, int], Path] = {}
    for cfg in configs:
        name = cfg.raw.machine.name
        if name in names:
            raise ConfigError("machine.name", f"{cfg.path} and {names[name]} both name "
                              f"the machine {name!r}; each machine needs its own name")
        names[name] = cfg.path
        state = cfg.state_dir.resolve()
        if state in dirs:
            raise ConfigError("state.dir", f"{cfg.path} and {dirs[state]} share the state "
                              f"directory {state}; give each machine its own state.dir")
        dirs[state] = cfg.path
        tel = cfg.raw.telemetry
        if tel.metrics_port is not None:
            ports[(tel.metrics_host, tel.metrics_port)] = cfg.path
    if len(ports) > 1:
        where = ", ".join(f"{p} ({h}:{n})" for (h, n), p in sorted(ports.items()))
        raise ConfigError("telemetry.metrics_port", f"one metrics endpoint per process, "
                          f"the files ask for several: {where}")


def metrics_endpoint(configs: list[LoadedConfig]) -> tuple[str, int] | None:
    for cfg in configs:
        tel = cfg.raw.telemetry
        if tel.metrics_port is not None:
            return tel.metrics_host, tel.metrics_port
    return None


def metrics_limits(configs: list[LoadedConfig]) -> HttpLimits:
    """The HTTP server's bounds: those of the first file that sets the endpoint."""
    for cfg in configs:
        if cfg.raw.telemetry.metrics_port is not None:
            return limits_from(cfg.raw.telemetry)
    return HttpLimits()


def machine_daemon(cfg: LoadedConfig, **kwargs: Any) -> Daemon:
    """A `Daemon` among others: it logs with its machine's name, sends no sd_notify
    of its own (the fleet's), and serves no endpoint (the fleet serves every
    machine's registry on one: `compd.faces.fleet_metrics`). Run it with
    `Daemon.serve` (the fleet holds the signal handlers)."""
    log = structlog.get_logger("compd").bind(machine=cfg.raw.machine.name)
    return Daemon(cfg, notifier=Notifier(None), serve_metrics=False, log=log, **kwargs)


class Fleet:
    """The machines of one directory, each a supervised task of one event loop."""

    def __init__(self, configs: list[LoadedConfig], *, dry_run: bool = False,
                 notifier: Notifier | None = None,
                 drivers: dict[str, Driver] | None = None,
                 clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], Awaitable[object]] | None = None) -> None:
        self.configs = {c.raw.machine.name: c for c in configs}
        #: every machine's clock and sleep (`Daemon`'s; a test steps them all in
        #: lockstep with one `compd.testing.SteppedClock`)
        self.clock = clock
        self.sleep = sleep
        #: drivers built (and so checked) before the start; a restart builds a fresh one
        self._drivers = dict(drivers or {})
        self.dry_run = dry_run
        self.notifier = notifier if notifier is not None else Notifier()
        self.daemons: dict[str, Daemon] = {}
        self.restarts: dict[str, int] = dict.fromkeys(self.configs, 0)
        self.metrics = FleetMetrics(self._machine_metrics)
        #: where /metrics is served: the files' endpoint; a worker of `compd run DIR
        #: --workers N` serves on a free loopback port for its parent
        #: (`compd.runtime.worker_main`)
        self.endpoint = metrics_endpoint(configs)
        self.stopping = asyncio.Event()
        self.log = structlog.get_logger("compd")

    def _machine_metrics(self) -> dict[str, Metrics]:
        return {name: d.metrics for name, d in list(self.daemons.items())}

    def _status_pages(self) -> Callable[[WSGIApp], WSGIApp] | None:
        """The operator page for every machine, None when no file enables [faces.http]."""
        enabled = [c.raw.faces.http for c in self.configs.values() if c.raw.faces.http.enabled]
        if not enabled:
            return None
        from compd.faces.status_http import fleet_document, with_status

        refresh_s = min(h.refresh_s for h in enabled)

        def document(history: bool) -> dict[str, Any]:
            boards = {name: d.status_board for name, d in list(self.daemons.items())
                      if d.running.cfg.raw.faces.http.enabled}
            return fleet_document(boards, refresh_s, history=history)

        return with_status(document, lambda: refresh_s)

    def request_stop(self, sig: signal.Signals | None = None) -> None:
        """SIGTERM and the other stop signals (`compd.runtime.signals`); None: a caller."""
        if sig is not None:
            level = "info" if sig in (signal.SIGTERM, signal.SIGINT) else "warning"
            getattr(self.log, level)("signal_received", signal=sig.name, action="stop")
        self.stopping.set()
        for daemon in list(self.daemons.values()):
            if sig is not None:
                daemon.loop.stop_signal = sig.name
            daemon.request_stop()

    def signal_ignored(self, sig: signal.Signals) -> None:
        self.log.warning("signal_ignored", signal=sig.name,
                         reason="SIGHUP reloads, SIGTERM stops compd cleanly")

    def request_reload(self) -> None:
        for daemon in list(self.daemons.values()):
            daemon.request_reload()

    async def run(self) -> int:
        """Run every machine until SIGTERM/SIGINT (or `request_stop`); returns 0."""
        pin_mmap_threshold()
        loop = asyncio.get_running_loop()
        # not the main thread: none installed, the caller stops us with request_stop()
        installed = signals.install(loop, stop=self.request_stop, reload=self.request_reload,
                                    ignored=self.signal_ignored)
        endpoint = self.endpoint
        if endpoint is not None:
            try:
                self.metrics.start_http(endpoint[1], endpoint[0], self._status_pages(),
                                        metrics_limits(list(self.configs.values())))
            except OSError as exc:
                self.log.error("metrics_unavailable", host=endpoint[0], port=endpoint[1],
                               error=str(exc))
        self.log.info("fleet_starting", machines=sorted(self.configs), dry_run=self.dry_run)
        names = sorted(self.configs)
        delays = staggered_starts(len(names), min(c.real_period_s
                                                  for c in self.configs.values()))
        tasks = [loop.create_task(self._supervise(name, delay), name=f"compd:{name}")
                 for name, delay in zip(names, delays, strict=True)]
        try:
            await gather_with(tasks, loop.create_task(self._notify()))
        finally:
            self.notifier.stopping()
            self.metrics.stop()
            signals.remove(loop, installed)
        self.log.info("fleet_stopped", machines=len(self.configs),
                      restarts=sum(self.restarts.values()))
        return 0

    async def _supervise(self, name: str, delay_s: float = 0.0) -> None:
        """Run one machine's daemon from `delay_s` on (`staggered_starts`); start it
        again after a crash, with backoff."""
        backoff = BACKOFF_INITIAL_S
        running = self.metrics.running.labels(machine=name)
        self.metrics.restarts.labels(machine=name)
        if delay_s > 0.0:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self.stopping.wait(), delay_s)
        while not self.stopping.is_set():
            daemon = machine_daemon(self.configs[name], dry_run=self.dry_run,
                                    driver=self._drivers.pop(name, None), clock=self.clock,
                                    sleep=self.sleep)
            self.daemons[name] = daemon
            started = self.clock()
            running.set(1)
            try:
                rc = await daemon.serve()
                if rc == 0 or self.stopping.is_set():
                    return  # stopped on request
                # its cycle broke (logged, shutdown policy applied, checkpoint written)
                running.set(0)
                if self.clock() - started >= BACKOFF_RESET_S:
                    backoff = BACKOFF_INITIAL_S
                self.log.error("machine_crashed", machine=name, error="cycle_broken",
                               type="exit", rc=rc, restart_in_s=backoff)
            except Exception as exc:  # this machine's failure, never the others'
                running.set(0)
                if self.clock() - started >= BACKOFF_RESET_S:
                    backoff = BACKOFF_INITIAL_S
                self.log.error("machine_crashed", machine=name, error=str(exc),
                               type=type(exc).__name__, restart_in_s=backoff,
                               exc_info=True)
            # the restart runs the config the machine ran (a reload's), not the file as
            # read at start; its cycle builds fresh model state from it and the checkpoint
            self.configs[name] = daemon.running.cfg
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self.stopping.wait(), backoff)
            backoff = min(backoff * 2.0, BACKOFF_CAP_S)
            if not self.stopping.is_set():
                self.restarts[name] += 1
                self.metrics.restarts.labels(machine=name).inc()
                self.log.info("machine_restarting", machine=name, restarts=self.restarts[name])

    async def _notify(self) -> None:
        """READY once every machine's task is started; WATCHDOG while the loop runs."""
        await asyncio.sleep(0)
        self.notifier.ready()
        interval = self.notifier.watchdog_interval_s()
        every = interval / 2.0 if interval else 10.0
        while True:
            ready = sum(1 for d in list(self.daemons.values()) if d.telemetry.complete_cycles)
            self.notifier.watchdog()
            self.notifier.status(f"{len(self.configs)} machines, {ready} compensating")
            await asyncio.sleep(every)
