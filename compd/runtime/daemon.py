"""The daemon: one machine's loop and its sinks, composed.

Per sample (`compd.runtime.loop`): read (channels, plus the offset when
read-back is on) → `Cycle.plan` (validate, step, fault policy, output stage)
→ write → `Cycle.commit` (the write's outcome: the final row;
`compd.runtime.cycle_io`, the one module that calls the cycle) → the
committed row fed to each sink (`compd.runtime.sinks`: recorder, telemetry
and sd_notify, status page, OPC UA face) → the checkpoint (every
state.checkpoint_every samples, on an alarm change, and on shutdown). One
`compd.runtime.clock.Clock` (monotonic, wall, sleep; injectable) is the time
of all of them.

`Daemon` composes them and holds what a process asks of a machine: the state
lock, the start from the checkpoint (`compd.runtime.startup`), certificates,
the driver, and the requests: SIGHUP reloads (`compd.runtime.reloading`: read
and validated in a worker thread while the loop keeps cycling, swapped in
between two cycles; a file that does not validate leaves the old config
running, ``reload_failed``). SIGUSR1, SIGUSR2, SIGXFSZ are logged
(``signal_ignored``) and otherwise ignored (`compd.runtime.signals`). A
re-zero (`rezero`: OPC UA Rezero, a `compd rezero` request found in the state
directory between two cycles, `compd.runtime.rezero_request`) is applied at
the start of the next cycle and checkpointed at once.
SIGTERM/SIGINT and every other signal whose default would end the process:
the current cycle finishes, then the shutdown policy ("hold", or
"ramp_to_zero" cycling until the offset is 0), a checkpoint, and `run()`
returns 0. A metrics port that cannot be bound is logged
(``metrics_unavailable``); compensation runs without the endpoint.

An exception where none is expected never ends the loop with the offset
frozen: one in a sink is logged (``cycle_error``, rate-limited:
`compd.runtime.journal`) and the cycle goes on; one from the driver's write
is a failed write; one from the cycle itself is logged and the cycle is
stepped again as a failed read. When that too raises, or the driver's read
raises something no driver should, the cycle is broken (``cycle_broken``):
the shutdown policy is tried, a checkpoint written, and `run()` returns
EX_SOFTWARE (70; systemd, or `compd run DIR`'s supervisor, restarts it).

`run` installs the process's signal handlers; `serve` is the machine alone,
as `compd run DIR` runs each of its machines (`compd.runtime.fleet`), with
``serve_metrics=False`` (the fleet serves every registry on one endpoint).
"""

from __future__ import annotations

import asyncio
import signal
import time
from collections.abc import Awaitable, Callable
from typing import Any

import structlog

from compd import __version__
from compd.config.loader import LoadedConfig
from compd.core.cycle import params_from_config
from compd.faces.status import StatusBoard
from compd.faces.telemetry import Metrics
from compd.runtime import signals
from compd.runtime.certcheck import check_certificates
from compd.runtime.clock import Clock
from compd.runtime.cycle_io import CycleIO, Running
from compd.runtime.driver_setup import connect
from compd.runtime.gcfreeze import freeze_long_lived
from compd.runtime.gcpolicy import PROCESS_GC
from compd.runtime.heap import pin_mmap_threshold
from compd.runtime.journal import Journal
from compd.runtime.loop import CycleLoop
from compd.runtime.reloading import Reloader
from compd.runtime.rezero_request import RezeroRequests
from compd.runtime.sdnotify import Notifier
from compd.runtime.sinks.base import CycleSink
from compd.runtime.sinks.checkpoint import CheckpointSink
from compd.runtime.sinks.opcua import OpcUaSink
from compd.runtime.sinks.recorder import RecorderSink
from compd.runtime.sinks.status import StatusSink
from compd.runtime.sinks.telemetry import TelemetrySink
from compd.runtime.startup import start_cycle
from drivers.base import Driver

__all__ = ["Daemon"]


class Daemon:
    """One controller, one model, one loop: the loop and its sinks, composed."""

    def __init__(self, cfg: LoadedConfig, *, dry_run: bool = False, once: bool = False,
                 driver: Driver | None = None, notifier: Notifier | None = None,
                 metrics: Metrics | None = None,
                 clock: Callable[[], float] = time.monotonic,
                 wall: Callable[[], float] = time.time,
                 sleep: Callable[[float], Awaitable[object]] | None = None,
                 serve_metrics: bool = True, log: Any = None) -> None:
        self.dry_run = dry_run
        self.once = once
        self.notifier = notifier if notifier is not None else Notifier()
        #: monotonic seconds (deadlines, machine time), wall seconds (sample ages,
        #: records, checkpoint age) and the wait until the next deadline: all
        #: injectable (`compd.testing.SteppedClock` drives the loop in lockstep)
        self.clock = Clock(mono=clock, wall=wall, sleep=sleep)
        self.metrics = metrics if metrics is not None else Metrics(mono=clock)
        #: what the operator page shows ([faces.http]), and the alarms listed on it
        http = cfg.raw.faces.http
        self.status_board = StatusBoard(history_h=http.history_h, refresh_s=http.refresh_s)
        self.journal = Journal(log if log is not None else structlog.get_logger("compd"),
                               self.status_board, self.clock)
        self.running = Running(cfg, params_from_config(cfg, dry_run=dry_run), driver)
        self.io = CycleIO(self.running, dry_run=dry_run, metrics=self.metrics,
                          journal=self.journal)
        self.recorder = RecorderSink(dry_run=dry_run, metrics=self.metrics,
                                     journal=self.journal)
        self.telemetry = TelemetrySink(metrics=self.metrics, notifier=self.notifier,
                                       board=self.status_board, journal=self.journal,
                                       serve=serve_metrics)
        self.opcua = OpcUaSink(metrics=self.metrics, operator_hold=self.operator_hold,
                               rezero=self.rezero)
        self.checkpoint = CheckpointSink(dry_run=dry_run, journal=self.journal)
        #: fed in this order every cycle; the checkpoint last, by the loop
        self.sinks: list[CycleSink] = [self.recorder, self.telemetry,
                                       StatusSink(self.status_board, dry_run=dry_run),
                                       self.opcua]
        self.reloader = Reloader(self.io, sinks=[*self.sinks, self.checkpoint],
                                 journal=self.journal, metrics=self.metrics, clock=self.clock)
        self.loop = CycleLoop(self.io, sinks=self.sinks, checkpoint=self.checkpoint,
                              journal=self.journal, metrics=self.metrics, clock=self.clock,
                              once=once, between=self._between,
                              reloads=lambda: self.reloader.reloads, gc_policy=PROCESS_GC)
        #: `compd rezero`'s requests in the state directory (`compd.runtime.rezero_request`)
        self.rezero_requests = RezeroRequests(None)
        self._lock: Any = None

    # -- requests (signals, the OPC UA face) -------------------------------------------

    def request_stop(self, sig: signal.Signals | None = None) -> None:
        """SIGTERM and the other stop signals (`compd.runtime.signals`); None: a caller."""
        if sig is not None:
            self.loop.stop_signal = sig.name
            level = "info" if sig in (signal.SIGTERM, signal.SIGINT) else "warning"
            getattr(self.journal.log, level)("signal_received", signal=sig.name,
                                             action="stop")
        self.loop.stop_requested.set()

    def request_reload(self) -> None:
        """SIGHUP: read and validate the config again; swap it in between two cycles."""
        if not self.once and not self.loop.stop_requested.is_set():
            self.reloader.request()

    def signal_ignored(self, sig: signal.Signals) -> None:
        self.journal.log.warning("signal_ignored", signal=sig.name,
                         reason="SIGHUP reloads, SIGTERM stops compd cleanly")

    def operator_hold(self, on: bool, who: str) -> bool:
        """An operator's hold (or its release) of the running cycle (OPC UA SetHold);
        checkpointed at once so that a restart keeps it. False before the cycle exists."""
        cycle = self.running.cycle
        try:
            event = self.io.operator_hold(on, who)
        except LookupError:
            return False
        if event is not None and cycle is not None:
            self.journal.events([event], alarms=False)
            self.checkpoint.save(self.running.cfg, cycle)
        return True

    def rezero(self, who: str) -> bool:
        """A re-zero (OPC UA Rezero, `compd rezero`): the present prediction becomes
        the new zero at the start of the next cycle, checkpointed at once. False
        before the cycle exists."""
        return self.io.request_rezero(who)

    async def _between(self) -> None:
        """Between two cycles: a reload swapped in, a `compd rezero` request taken."""
        await self.reloader.swap()
        box = self.rezero_requests
        who = box.take(self.clock.wall())
        if who is not None:
            self.rezero(who)
        elif box.refused is not None:
            self.journal.log.warning("rezero_request_refused", reason=box.refused)
            box.refused = None

    # -- running -------------------------------------------------------------------------

    async def run(self) -> int:
        """Run until stopped (or one cycle with `once`); returns the exit status."""
        pin_mmap_threshold()  # months of cycles must not fragment the C heap (compd.runtime.heap)
        loop = asyncio.get_running_loop()
        # not the main thread: none installed, the caller stops us with request_stop()
        installed = signals.install(loop, stop=self.request_stop, reload=self.request_reload,
                                    ignored=self.signal_ignored)
        try:
            return await self.serve()
        finally:
            signals.remove(loop, installed)

    async def serve(self) -> int:
        """The machine alone: `run` without the process's signal handlers and heap
        setting (`compd run DIR` runs several machines so, `compd.runtime.fleet`)."""
        cfg = self.running.cfg
        if not self.dry_run:
            from compd.runtime.statelock import StateLock

            self._lock = StateLock(cfg.state_dir)
            self._lock.acquire()  # StateLocked propagates: the caller reports it
        try:
            directory = None if self._lock is None else self._lock.directory
            self.checkpoint.directory = directory
            self.rezero_requests.directory = directory
            startup = start_cycle(cfg, self.running.params, directory=directory,
                                  wall_s=self.clock.wall())
            self.running.cycle = startup.cycle
            self.journal.events(startup.events)
            self._log_start(startup.mode)
            check_certificates(cfg, self.metrics, self.journal.log, wall_s=self.clock.wall())
            await self.recorder.open(cfg)
            await self.telemetry.open(cfg)
            if self.running.driver is None:
                from compd.runtime.driver_setup import build_driver

                self.running.driver = build_driver(cfg)
            await self.opcua.open(cfg)
            try:
                if not await connect(self.running.driver, cfg, self.journal.log):
                    self.io.unannounced = cfg.raw.controller.endpoint
                # full GC pauses stall every machine's loop (gcfreeze.py): the objects
                # made so far (driver connected) are frozen before the first deadline
                freeze_long_lived()
                # and full collections only between cycles, once a minute (gcpolicy.py)
                gc_policy = self.loop.gc_policy or PROCESS_GC
                gc_policy.install()
                try:
                    return await self.loop.run()
                finally:
                    gc_policy.uninstall()
            finally:
                await self.reloader.cancel()
                if self.running.driver is not None:
                    await self.running.driver.close()
                await self.opcua.close()
        finally:
            await self.telemetry.close()
            await self.recorder.close()
            if self._lock is not None:
                # a save handed to the disk thread writes through the lock's directory
                # descriptor: it must be done before that closes (a cancelled loop)
                self.checkpoint.writer.drain()
                self._lock.release()

    def _log_start(self, mode: str) -> None:
        cfg, log = self.running.cfg, self.journal.log
        log.info("daemon_starting", version=__version__, machine=cfg.raw.machine.name,
                 protocol=cfg.raw.controller.protocol,
                 endpoint=cfg.raw.controller.endpoint, model=cfg.model.name,
                 shadow=cfg.shadow.name if cfg.shadow else None, start=mode,
                 dry_run=self.dry_run, period_s=cfg.period_s,
                 time_scale=cfg.raw.machine.time_scale)
        # what this daemon may write, and which config says so (an audit line)
        log.info("outputs_configured",
                 outputs={n: a.describe() for n, a in cfg.outputs.items()},
                 config_sha256=cfg.config_sha256, model_sha256=cfg.model_sha256,
                 dry_run=self.dry_run)
        if cfg.recorder_only:
            log.warning("recorder_only", model=cfg.model.name if cfg.model_given else None,
                        action="reading, validating and recording; nothing is "
                               "written to the controller")
