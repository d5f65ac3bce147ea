"""The asyncio shell around the pure cycle: deadlines, I/O, logging, state.

Per sample: read (channels, plus the offset when read-back is on) → `Cycle.plan`
(validate, step, fault policy, output stage) → write → `Cycle.commit` (the
write's outcome: the final row) → record → checkpoint
(every state.checkpoint_every samples and on shutdown).

Scheduling (`compd.core.schedule`): absolute deadlines on `time.monotonic`,
one every period / time_scale real seconds. A cycle that ends past its next
deadline is an overrun: counted, logged, and the schedule skips to the next
deadline in the future (never a burst of catch-up cycles).

Driver errors on read are a failed read (the cycle holds); the driver
reconnects by itself with its backoff. Write errors go back to the cycle
(transient: retried next cycle; permanent: offset writes stop, alarm).

SIGHUP reloads (`compd.runtime.reload`): the config and model are read and
validated in a worker thread while the loop keeps cycling, then swapped in
between two cycles (``reload_succeeded``); a changed endpoint or address gets
a new driver, connected before the swap; a file that does not validate, or a
change that needs a restart, leaves the old config running (``reload_failed``
with the key and the reason); so does any exception while the new cycle is
built. SIGUSR1, SIGUSR2, SIGXFSZ (whose default action ends a process at once,
with no checkpoint and no shutdown policy) are logged (``signal_ignored``) and
otherwise ignored (`compd.runtime.signals`). A metrics port that cannot be bound is logged
(``metrics_unavailable``); compensation runs without the endpoint. With
``[faces.http]`` the same server answers the operator page: the loop publishes
a snapshot per cycle (`compd.faces.status`), the HTTP threads only read it.

SIGTERM/SIGINT, and every other signal whose default would end the process
(SIGALRM, SIGXCPU, SIGPWR, ...: `compd.runtime.signals`): the current cycle
finishes, then the shutdown policy: "hold" leaves the offset where it is,
"ramp_to_zero" keeps cycling the ramp until the offset is 0; a checkpoint is
written and `run()` returns 0. The signal is named in the log.

An exception where none is expected never ends the loop with the offset frozen:
one in a sink (recorder, telemetry, the faces) is logged (``cycle_error``,
rate-limited) and the cycle goes on; one from the driver's write is a failed
write; one from the cycle itself is logged and the cycle is stepped again as
a failed read, so the fault policy holds and then ramps. When that too raises,
or the driver's read raises something no driver should (a bug: only a fresh
driver mends it), the cycle is broken (``cycle_broken``): the shutdown policy
is tried, a checkpoint written, and `run()` returns EX_SOFTWARE (70; systemd,
or `compd run DIR`'s supervisor, restarts it).
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import math
import signal
import time
from collections.abc import Awaitable, Callable, Mapping
from typing import TYPE_CHECKING, Any

import structlog

from compd import __version__
from compd.config.loader import PROBE_NAMES, LoadedConfig
from compd.core.adaptation import ProbeReading
from compd.core.cycle import WRITTEN, Cycle, CycleResult, Outcome, Plan, params_from_config
from compd.core.faults import GAUGE_ALARM, Event
from compd.core.schedule import Schedule, shutdown_ramp_cycles
from compd.faces.http_server import limits_from
from compd.faces.status import StatusBoard
from compd.faces.telemetry import Metrics, WSGIApp
from compd.runtime import signals
from compd.runtime.gcfreeze import freeze_long_lived
from compd.runtime.heap import pin_mmap_threshold
from compd.runtime.liveness import boot_id
from compd.runtime.reload import Changes
from compd.runtime.repeats import RepeatLimiter
from compd.runtime.sdnotify import Notifier
from compd.runtime.startup import checkpoint_path, start_cycle
from compd.sysexits import EX_SOFTWARE
from drivers.base import Driver, Quality, Sample
from drivers.errors import DriverError, WriteRejected

if TYPE_CHECKING:
    from compd.faces.opcua_face import OpcUaFace

#: STATUS= is sent on a state change or at least this often (cycles)
_STATUS_EVERY = 10


class Daemon:
    """One controller, one model, one loop."""

    def __init__(self, cfg: LoadedConfig, *, dry_run: bool = False, once: bool = False,
                 driver: Driver | None = None, notifier: Notifier | None = None,
                 metrics: Metrics | None = None,
                 clock: Callable[[], float] = time.monotonic,
                 wall: Callable[[], float] = time.time,
                 sleep: Callable[[float], Awaitable[object]] | None = None) -> None:
        self.cfg = cfg
        self.dry_run = dry_run
        self.once = once
        self.params = params_from_config(cfg, dry_run=dry_run)
        self._driver = driver
        self.notifier = notifier if notifier is not None else Notifier()
        self.metrics = metrics if metrics is not None else Metrics()
        #: monotonic seconds (deadlines, machine time), wall seconds (sample ages,
        #: records, checkpoint age) and the wait until the next deadline: all
        #: injectable (`compd.testing.SteppedClock` drives the loop in lockstep)
        self.clock = clock
        self.wall = wall
        self._sleep = sleep
        self.log = structlog.get_logger("compd")
        self.stop_requested = asyncio.Event()
        self.cycles = 0
        self.complete_cycles = 0
        self.overruns = 0
        self.last_result: CycleResult | None = None
        self.cycle: Cycle | None = None
        self._ready_sent = False
        self._read_ok: bool | None = None
        self._last_status = ""
        self._recorder: Any = None
        self._recorder_alarm = False
        self._lock: Any = None
        self._write_failures = RepeatLimiter("write_failed")
        #: a probe counter stepping every cycle with every probe refused: once, then summaries
        self._probe_refusals = RepeatLimiter("probe_refused")
        #: exceptions where none is expected, per stage of the cycle (once, then summaries)
        self._cycle_errors: dict[str, RepeatLimiter] = {}
        #: the signal that asked us to stop (None: request_stop() called directly)
        self.stop_signal: str | None = None
        #: (wall, monotonic) time of the last complete cycle: the health evidence
        self._last_complete: tuple[float, float] | None = None
        #: whether the last checkpoint said alarm (`compd health --state-dir` reads it)
        self._alarm_checkpointed = False
        #: SIGHUP: the reload being prepared, and what it produced for the loop to swap in
        self._reload_task: asyncio.Task[None] | None = None
        self._reload_again = False
        self._pending: tuple[LoadedConfig, Changes, Driver | None] | None = None
        self.reloads = 0
        #: [faces.opcua] once started
        self.opcua_face: OpcUaFace | None = None
        self._face_start: asyncio.Task[None] | None = None
        #: what the operator page shows ([faces.http]); published once per cycle
        http = cfg.raw.faces.http
        self.status_board = StatusBoard(history_h=http.history_h, refresh_s=http.refresh_s)
        #: the probe's values read this cycle ([adaptation]), None when not configured
        self._probe: ProbeReading | None = None
        self._controller_off: str | None = None

    # -- public --------------------------------------------------------------------

    def request_stop(self, sig: signal.Signals | None = None) -> None:
        """SIGTERM and the other stop signals (`compd.runtime.signals`); None: a caller."""
        if sig is not None:
            self.stop_signal = sig.name
            level = "info" if sig in (signal.SIGTERM, signal.SIGINT) else "warning"
            getattr(self.log, level)("signal_received", signal=sig.name, action="stop")
        self.stop_requested.set()

    def request_reload(self) -> None:
        """SIGHUP: read and validate the config again; swap it in between two cycles."""
        if self.once or self.stop_requested.is_set():
            return
        if self._reload_task is not None and not self._reload_task.done():
            self._reload_again = True  # the file may have changed after it was read
            return
        self.log.info("reload_requested", config=str(self.cfg.path))
        self._reload_task = asyncio.get_running_loop().create_task(self._prepare_reload())

    def signal_ignored(self, sig: signal.Signals) -> None:
        self.log.warning("signal_ignored", signal=sig.name,
                         reason="SIGHUP reloads, SIGTERM stops compd cleanly")

    async def run(self) -> int:
        """Run until stopped (or one cycle with `once`); returns the exit status."""
        pin_mmap_threshold()  # months of cycles must not fragment the C heap (compd.runtime.heap)
        loop = asyncio.get_running_loop()
        # not the main thread: none installed, the caller stops us with request_stop()
        installed = signals.install(loop, stop=self.request_stop, reload=self.request_reload,
                                    ignored=self.signal_ignored)
        try:
            return await self._run()
        finally:
            signals.remove(loop, installed)

    # -- the loop ------------------------------------------------------------------------

    async def _run(self) -> int:
        cfg = self.cfg
        writing_state = not self.dry_run
        if writing_state:
            from compd.runtime.statelock import StateLock

            self._lock = StateLock(cfg.state_dir)
            self._lock.acquire()  # StateLocked propagates: the caller reports it
        try:
            startup = start_cycle(cfg, self.params, directory=self._state_directory(),
                                  wall_s=self.wall())
            self.cycle = startup.cycle
            self._log_events(startup.events)
            self.log.info("daemon_starting", version=__version__, machine=cfg.raw.machine.name,
                          protocol=cfg.raw.controller.protocol,
                          endpoint=cfg.raw.controller.endpoint, model=cfg.model.name,
                          shadow=cfg.shadow.name if cfg.shadow else None,
                          start=startup.mode, dry_run=self.dry_run,
                          period_s=cfg.period_s, time_scale=cfg.raw.machine.time_scale)
            # what this daemon may write, and which config says so (an audit line)
            self.log.info("outputs_configured",
                          outputs={n: a.describe() for n, a in cfg.outputs.items()},
                          config_sha256=cfg.config_sha256, model_sha256=cfg.model_sha256,
                          dry_run=self.dry_run)
            self._check_certificates()
            self._open_recorder()
            self._configure_metrics()
            self._start_metrics()
            driver = self._driver
            if driver is None:
                from compd.runtime.driver_setup import build_driver

                driver = self._driver = build_driver(cfg)
            await self._start_opcua_face()
            try:
                await self._connect(driver)
                # full GC pauses stall every machine's loop (gcfreeze.py): the objects
                # made so far (driver connected) are frozen before the first deadline
                freeze_long_lived()
                rc = await self._loop()
            finally:
                await self._cancel_reload()
                await (self._driver or driver).close()
                await self._stop_opcua_face()
            return rc
        finally:
            self.notifier.stopping()
            if self._recorder is not None:
                self._recorder.close()
            self.metrics.stop()
            if self._lock is not None:
                self._lock.release()

    async def _start_opcua_face(self) -> None:
        """[faces.opcua]: compd's own OPC UA server, started beside the loop (it takes
        seconds; compensation starts at once and never waits for it)."""
        if not self.cfg.raw.faces.opcua.enabled:
            return
        from compd.faces.opcua_face import OpcUaFace

        face = OpcUaFace(self.cfg, self.operator_hold, self.metrics.registry)

        async def start() -> None:
            if await face.start():
                self.opcua_face = face

        self._face_start = asyncio.get_running_loop().create_task(start(),
                                                                  name="opcua-face-start")

    async def _stop_opcua_face(self) -> None:
        starting, self._face_start = self._face_start, None
        if starting is not None:
            await asyncio.gather(starting, return_exceptions=True)
        face, self.opcua_face = self.opcua_face, None
        if face is not None:
            await face.stop()

    def operator_hold(self, on: bool, who: str) -> bool:
        """An operator's hold (or its release) of the running cycle (OPC UA SetHold);
        checkpointed at once so that a restart keeps it. False before the cycle exists."""
        cycle = self.cycle
        if cycle is None:
            return False
        event = cycle.set_operator_hold(on, who)
        if event is not None:
            self.log.warning(event.name, **event.fields)
            self._checkpoint(cycle)
        return True

    def _configure_metrics(self) -> None:
        from compd import __version__

        cfg = self.cfg
        self.metrics.configure({n: ch.unit for n, ch in cfg.raw.channels.items()},
                               list(cfg.outputs), version=__version__,
                               model_sha256=cfg.model_sha256, config_sha256=cfg.config_sha256)
        self.metrics.period_seconds.set(cfg.real_period_s)

    def _start_metrics(self) -> None:
        port = self.cfg.raw.telemetry.metrics_port
        host = self.cfg.raw.telemetry.metrics_host
        if port is None:
            if self.cfg.raw.faces.http.enabled:
                self.log.warning("status_page_unavailable", reason="[faces.http] is served "
                                 "beside /metrics: it needs [telemetry] metrics_port")
            return
        try:
            self.metrics.start_http(port, host, self._status_pages(),
                                    limits_from(self.cfg.raw.telemetry))
        except OSError as exc:  # a port in use: compensation never stops for telemetry
            self.log.error("metrics_unavailable", host=host, port=port, error=str(exc),
                           hint="compd health --url will report unhealthy; free the port "
                                "or change telemetry.metrics_port")

    def _status_pages(self) -> Callable[[WSGIApp], WSGIApp] | None:
        """The operator page's wrapper of the metrics app, None without [faces.http]."""
        http = self.cfg.raw.faces.http
        if not http.enabled:
            return None
        from compd.faces.status_http import daemon_document, with_status

        board = self.status_board
        board.history_h, board.refresh_s = http.history_h, http.refresh_s  # a reload
        return with_status(lambda history: daemon_document(board, history=history),
                           lambda: board.refresh_s)

    async def _connect(self, driver: Driver, cfg: LoadedConfig | None = None) -> None:
        ctl = (cfg or self.cfg).raw.controller
        try:
            await asyncio.wait_for(driver.connect(), ctl.connect_timeout_s)
            self.log.info("controller_connected", endpoint=ctl.endpoint)
        except (DriverError, TimeoutError, OSError) as exc:
            # not fatal: the reads fail (hold) and the driver retries with backoff
            self.log.warning("controller_connect_failed", error=str(exc))

    async def _loop(self) -> int:
        schedule = Schedule(self.cfg.real_period_s, self.clock(),
                            time_scale=self.cfg.raw.machine.time_scale)
        shutdown_cycles_left: int | None = None
        broken = False
        while True:
            if self._pending is not None and shutdown_cycles_left is None:
                try:
                    await self._swap()  # between two cycles: the reloaded config
                except Exception as exc:  # after the handover (reopening a sink): go on
                    self._cycle_error("reload", exc)
            driver, cycle = self._driver, self.cycle
            assert driver is not None and cycle is not None
            started = self.clock()
            now_s = schedule.machine_s(started)
            try:
                result = await self._one_cycle(driver, cycle, now_s)
            except Exception as exc:  # the cycle raised even as a failed read: broken
                self.log.error("cycle_broken", error=f"{type(exc).__name__}: {exc}",
                               sequence=cycle.sequence, offset_um=cycle.output.current_um,
                               shutdown=self.cfg.raw.faults.shutdown, exc_info=True)
                self.status_board.alarm("cycle_broken", "error",
                                        {"error": f"{type(exc).__name__}: {exc}"})
                if broken or shutdown_cycles_left is not None or self.once:
                    break  # the ramp cannot go on either: what is left is the checkpoint
                broken = True
                if self.cfg.raw.faults.shutdown != "ramp_to_zero" or self.dry_run:
                    break
                # the shutdown policy: the ramp needs no input and no model
                cycle.begin_shutdown()
                p = self.params
                shutdown_cycles_left = shutdown_ramp_cycles(p.limit_um, p.slew_um_s,
                                                            p.period_s)
                self.log.info("shutdown_requested", policy="ramp_to_zero",
                              offset_um=cycle.output.current_um, reason="cycle_broken")
                schedule.advance(self.clock())
                await self._pause(schedule.wait_s(self.clock()))
                continue
            self.metrics.cycle_seconds.observe(self.clock() - started)
            if self.once:
                self._checkpoint(cycle)
                return 0 if result.complete else 1
            if self._should_checkpoint(result):
                self._checkpoint(cycle)
            if shutdown_cycles_left is not None:
                shutdown_cycles_left -= 1
                if result.shutdown_done or shutdown_cycles_left <= 0:
                    self.log.info("shutdown_ramp_finished", offset_um=result.offset_um,
                                  reached_zero=result.shutdown_done)
                    break
            elif self.stop_requested.is_set():
                if self.cfg.raw.faults.shutdown == "ramp_to_zero" and not self.dry_run:
                    cycle.begin_shutdown()
                    self.stop_requested = asyncio.Event()  # a second signal ends the ramp
                    p = self.params
                    shutdown_cycles_left = shutdown_ramp_cycles(p.limit_um, p.slew_um_s,
                                                                p.period_s)
                    self.log.info("shutdown_requested", policy="ramp_to_zero",
                                  offset_um=result.offset_um, signal=self.stop_signal)
                else:
                    self.log.info("shutdown_requested", policy="hold",
                                  offset_um=result.offset_um, signal=self.stop_signal)
                    break
            missed = schedule.advance(self.clock())
            if missed:
                self.overruns += 1
                self.metrics.overruns.inc()
                self.log.warning("cycle_overrun", sequence=result.sequence,
                                 skipped_deadlines=missed, overruns=self.overruns)
            await self._pause(schedule.wait_s(self.clock()))
            if shutdown_cycles_left is not None and self.stop_requested.is_set():
                self.log.warning("shutdown_ramp_interrupted", offset_um=cycle.output.current_um)
                break
        self._checkpoint(cycle)
        self.log.info("daemon_stopped", cycles=self.cycles, overruns=self.overruns,
                      offset_um=cycle.output.current_um, reloads=self.reloads,
                      signal=self.stop_signal, broken=broken)
        return EX_SOFTWARE if broken else 0

    async def _pause(self, delay_s: float) -> None:
        """Until the next deadline (`delay_s` on the injected clock) or a stop request."""
        if self._sleep is None:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self.stop_requested.wait(), delay_s)
            return
        stop = asyncio.ensure_future(self.stop_requested.wait())
        nap = asyncio.ensure_future(self._sleep(max(0.0, delay_s)))
        try:
            await asyncio.wait({stop, nap}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            stop.cancel()
            nap.cancel()
            await asyncio.gather(stop, nap, return_exceptions=True)

    # -- reload (SIGHUP) ----------------------------------------------------------------

    async def _prepare_reload(self) -> None:
        """Load and validate the config again (a worker thread: the loop keeps cycling);
        connect a new driver when the controller side changed. The loop swaps."""
        from compd.errors import ConfigError
        from compd.runtime.reload import prepare

        while True:
            self._reload_again = False
            try:
                new, changes = await asyncio.to_thread(prepare, self.cfg)
                driver: Driver | None = None
                if changes.controller:
                    from compd.runtime.driver_setup import build_driver

                    driver = build_driver(new)
                    await self._connect(driver, new)
            except ConfigError as exc:
                self.log.error("reload_failed", key=exc.key, reason=exc.reason,
                               config=str(self.cfg.path), kept=self.cfg.config_sha256)
            except Exception as exc:  # never the loop's end: the old config keeps running
                self.log.error("reload_failed", key="", reason=f"{type(exc).__name__}: {exc}",
                               config=str(self.cfg.path), kept=self.cfg.config_sha256)
            else:
                if self._pending is not None and self._pending[2] is not None:
                    await self._pending[2].close()  # superseded before it was swapped in
                self._pending = (new, changes, driver)
            if not self._reload_again:
                return

    async def _cancel_reload(self) -> None:
        task = self._reload_task
        if task is not None and not task.done():
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        if self._pending is not None and self._pending[2] is not None:
            await self._pending[2].close()
        self._pending = None

    async def _swap(self) -> None:
        """Put the prepared config in place of the running one, between two cycles."""
        from compd.runtime.reload import handover

        assert self._pending is not None and self.cycle is not None
        new, changes, driver = self._pending
        self._pending = None
        old_cfg, old_driver = self.cfg, self._driver
        try:
            params = params_from_config(new, dry_run=self.dry_run)
            cycle = handover(self.cycle, new, params, changes)
        except Exception as exc:  # never the loop's end: the old config keeps running
            self.log.error("reload_failed", key="", reason=f"{type(exc).__name__}: {exc}",
                           config=str(new.path), kept=old_cfg.config_sha256, exc_info=True)
            if driver is not None:
                with contextlib.suppress(Exception):
                    await driver.close()
            return
        self.cycle = cycle
        self.cfg, self.params = new, params
        if driver is not None:
            self._driver = driver
            self._read_ok = None
            if old_driver is not None:
                await old_driver.close()
        if changes.recorder:
            if self._recorder is not None:
                self._recorder.close()
                self._recorder = None
            self._open_recorder()
        if changes.metrics:
            self.metrics.stop()
            self._start_metrics()
        self.reloads += 1
        self.log.info("reload_succeeded", changed=changes.names(),
                      config_sha256=new.config_sha256, model_sha256=new.model_sha256,
                      was_config_sha256=old_cfg.config_sha256,
                      was_model_sha256=old_cfg.model_sha256, model=new.model.name,
                      filters="restart_at_steady_state" if changes.model else "carried_over",
                      offset_um=self.cycle.output.current_um)
        self.log.info("outputs_configured",
                      outputs={n: a.describe() for n, a in new.outputs.items()},
                      config_sha256=new.config_sha256, model_sha256=new.model_sha256,
                      dry_run=self.dry_run)
        self._configure_metrics()
        self._check_certificates()

    async def _read(self, driver: Driver) -> tuple[dict[str, Sample] | None, float | None]:
        names = list(self.cfg.channels)
        if self.params.readback:
            names.append(self.params.offset_name)
        names.extend(self.cfg.probes)
        names.extend(self.cfg.states)
        self._controller_off = None
        limit_s = max(self.cfg.real_period_s, 2.0 * self.cfg.raw.controller.timeout_s)
        try:
            got = await asyncio.wait_for(driver.read(names), limit_s)
        except (DriverError, TimeoutError) as exc:  # anything else is a driver's bug:
            # the loop's cycle_broken (shutdown policy, checkpoint, a restart: a fresh driver)
            if self._read_ok is not False:
                self.log.warning("read_failed", error=str(exc), type=type(exc).__name__)
            self._read_ok = False
            self.metrics.read_errors.labels(channel=getattr(exc, "channel", None) or "*").inc()
            return None, None
        if self._read_ok is False:
            self.log.info("controller_reconnected")
        self._read_ok = True
        readback: float | None = None
        if self.params.readback:
            rb = got.get(self.params.offset_name)
            if rb is not None and rb.quality is not Quality.BAD:
                readback = float(rb.value)
        self._probe = _probe_reading(got) if self.cfg.probes else None
        self._controller_off = _controller_off(got) if self.cfg.states else None
        return {n: got[n] for n in self.cfg.channels if n in got}, readback

    async def _one_cycle(self, driver: Driver, cycle: Cycle, now_s: float) -> CycleResult:
        self._probe = None
        samples, readback = await self._read(driver)
        try:
            if self._probe is not None:
                plan = cycle.plan(now_s, samples, readback, wall_s=self.wall(),
                                  probe=self._probe, controller_off=self._controller_off)
            else:
                plan = cycle.plan(now_s, samples, readback, wall_s=self.wall(),
                                  controller_off=self._controller_off)
        except Exception as exc:
            # the fault policy decides what reaches the machine: this cycle is a failed
            # read (hold, then ramp after hold_s). Raises when the cycle cannot even do
            # that (the loop's cycle_broken).
            self._cycle_error("step", exc)
            samples = None
            plan = cycle.plan(now_s, None, readback, wall_s=self.wall(),
                              controller_off=self._controller_off)
        self.cycles += 1
        self._log_events(list(plan.events))
        outcome = await self._write(driver, plan)
        result = cycle.commit(outcome)
        self._log_events(list(result.write_events))
        confirmed = self.dry_run or (bool(plan.writes) and outcome.ok)
        if confirmed and not self.dry_run:
            self._log_repeat(self._write_failures.succeeded(self.clock()))
        self.last_result = result
        # the sinks: none of them may stop the cycle (the offset is written already)
        self._sink("record", self._record, result)
        self._sink("telemetry", self._telemetry, result, samples, confirmed)
        if self.cfg.raw.faces.http.enabled:
            self._sink("status_page", self.status_board.publish, result, self.cfg,
                       dry_run=self.dry_run)
        if self.opcua_face is not None:  # a snapshot; the face writes it in its own task
            self._sink("opcua_face", self.opcua_face.publish, result)
        if result.snapshot.adaptation is not None:
            self._sink("adaptation_metrics", self._adaptation_metrics, result)
        return result

    async def _write(self, driver: Driver, plan: Plan) -> Outcome:
        """The plan's writes (none in a dry run), and how they went."""
        if self.dry_run or not plan.writes:
            return WRITTEN
        try:
            await driver.write(plan.writes)
        except WriteRejected as exc:
            self.metrics.write_errors.labels(output=exc.channel or "*").inc()
            return Outcome.failed(exc.channel, permanent=exc.permanent, reason=str(exc))
        except DriverError as exc:
            self.metrics.write_errors.labels(output=exc.channel or "*").inc()
            return Outcome.failed(exc.channel, reason=str(exc))
        except Exception as exc:  # a driver's bug: a transient write failure
            self.metrics.write_errors.labels(output="*").inc()
            return Outcome.failed(None, reason=f"{type(exc).__name__}: {exc}")
        return WRITTEN

    def _adaptation_metrics(self, result: CycleResult) -> None:
        view = result.snapshot.adaptation
        if view is not None:
            self.metrics.adaptation(view.bias_um, view.bias_sigma_um, view.correction_um,
                                    result.record.probe, view.standing_down, view.model_worse)

    def _sink(self, stage: str, fn: Callable[..., object], *args: Any, **kwargs: Any) -> None:
        try:
            fn(*args, **kwargs)
        except Exception as exc:
            self._cycle_error(stage, exc)
        else:
            limiter = self._cycle_errors.get(stage)
            if limiter is not None:
                self._log_repeat(limiter.succeeded(self.clock()))

    def _cycle_error(self, stage: str, exc: Exception) -> None:
        """An exception where none is expected: one line with it (then a summary a
        minute while it repeats), an alarm on the status page."""
        limiter = self._cycle_errors.setdefault(stage, RepeatLimiter("cycle_error"))
        line = limiter.failed(self.clock(), {"stage": stage,
                                             "error": f"{type(exc).__name__}: {exc}"})
        if line is not None:
            name, fields = line
            self.log.error(name, **fields, exc_info=exc if name == "cycle_error" else None)
            with contextlib.suppress(Exception):
                self.status_board.alarm(name, "error", fields)

    def _check_certificates(self) -> None:
        sec = self.cfg.raw.controller.security
        if sec is None:
            return
        from compd.runtime.certcheck import WARN_DAYS, expiry_days, expiry_timestamp

        base = self.cfg.path.parent
        for role, path in (("client", sec.certificate), ("server", sec.server_certificate)):
            if path is None:
                continue
            full = path if path.is_absolute() else base / path
            try:
                days = expiry_days(full)
                self.metrics.certificate_expiry.labels(role=role).set(expiry_timestamp(full))
            except (OSError, ValueError) as exc:
                self.log.warning("certificate_unreadable", role=role, path=str(full),
                                 error=str(exc))
                continue
            if days <= WARN_DAYS:
                self.log.warning("certificate_expiring", role=role, path=str(full),
                                 days_left=round(days, 2), warn_days=WARN_DAYS)

    # -- record, checkpoint, telemetry ---------------------------------------------------

    def _open_recorder(self) -> None:
        path = self.cfg.recorder_path
        if self.dry_run or path is None:
            return
        from compd.runtime.recorder import Recorder

        rc = self.cfg.raw.recorder
        # retention as a row count (one row per cycle): never judged by a clock that can jump
        keep_rows = (max(1, math.ceil(rc.retention_days * 86400.0 / self.cfg.period_s))
                     if rc.retention_days else None)
        recorder = Recorder(path, commit_every=rc.commit_every, keep_rows=keep_rows)
        try:
            recorder.open()
        except Exception as exc:  # compensation never stops for the recorder
            self.log.error("recorder_unavailable", path=str(path), error=str(exc))
            return
        self._recorder = recorder

    def _record(self, result: CycleResult) -> None:
        if self._recorder is None:
            return
        dropped = self._recorder.dropped
        self._recorder.record(dataclasses.replace(result.record, wall_s=self.wall()))
        if self._recorder.dropped > dropped:
            self.metrics.records_dropped.inc(self._recorder.dropped - dropped)
        alarm = bool(self._recorder.alarm)
        if alarm != self._recorder_alarm:
            # compensation goes on either way; the alarm tells that samples are lost
            self._recorder_alarm = alarm
            self.metrics.recorder_alarm.set(1 if alarm else 0)
            if alarm:
                self.log.error("recorder_failing", error=self._recorder.last_error,
                               dropped=self._recorder.dropped)
            else:
                self.log.info("recorder_recovered", dropped=self._recorder.dropped)

    def _state_directory(self) -> Any:
        """The state directory the lock holds open (None without a lock: dry run)."""
        return None if self._lock is None else self._lock.directory

    def _should_checkpoint(self, result: CycleResult) -> bool:
        every = self.cfg.raw.state.checkpoint_every
        alarm = result.state.gauge >= GAUGE_ALARM
        if alarm != self._alarm_checkpointed:  # health --state-dir sees it now, as --url does
            self._alarm_checkpointed = alarm
            return True
        return result.sequence % every == 0

    def _checkpoint(self, cycle: Cycle) -> None:
        if self.dry_run:
            return
        from compd.runtime.checkpoint import save_checkpoint

        try:
            state = cycle.export_state()
            state.update(saved_mono_s=self.clock(), model_sha256=self.cfg.model_sha256,
                         config_sha256=self.cfg.config_sha256)
            if self._last_complete is not None:  # what `compd health --state-dir` judges
                wall_s, mono_s = self._last_complete
                state.update(last_complete_wall_s=wall_s, last_complete_mono_s=mono_s,
                             boot_id=boot_id())
            if self.last_result is not None:  # an alarm is unhealthy however recent the above
                state["last_state"] = str(self.last_result.state)
            save_checkpoint(checkpoint_path(self.cfg), state,
                            directory=self._state_directory())
        except Exception as exc:  # a failed checkpoint must not stop the loop
            self.log.error("checkpoint_failed", error=str(exc))

    def _telemetry(self, result: CycleResult, samples: dict[str, Sample] | None,
                   confirmed: bool) -> None:
        m = self.metrics
        m.offset_um.set(result.offset_um)
        m.fault_state.set(result.state.gauge)
        m.model_output(result.model_um, result.record.validity)
        if samples:
            for name, s in samples.items():
                if math.isfinite(s.value):
                    m.channel(name, s.value)
        for name, reason in result.record.validity.items():
            if reason is not None and reason != "read_failed":
                m.read_errors.labels(channel=name).inc()
        self.log.debug("cycle", sequence=result.sequence, state=result.state,
                       offset_um=round(result.offset_um, 4), model_um=result.model_um,
                       shadow_um=result.shadow_um, status=result.status)
        if result.in_force:  # complete (compd.core.cycle.offset_in_force): what the
            # model asks for is in force (never a held, faulted or unconfirmed offset)
            self.complete_cycles += 1
            m.cycle_complete()
            self._last_complete = (self.wall(), self.clock())
        if not self._ready_sent and (result.complete or self._read_ok):
            # up: the loop runs and the controller answers (a broken sensor at start is a
            # fault the policy handles, hold then ramp with the alarm, not a start failure)
            self.notifier.ready()
            self._ready_sent = True
            self.log.info("ready", sequence=result.sequence,
                          offset_um=round(result.offset_um, 4), complete=result.complete)
        if self._ready_sent:
            # the loop is alive: systemd restarting us would not mend a sensor or a link,
            # and a restart would reset the fault policy's hold timer (never ramping)
            self.notifier.watchdog()
        state = str(result.state)
        if state != self._last_status or result.sequence % _STATUS_EVERY == 0:
            self.notifier.status(f"offset {result.offset_um:.2f} um, state {state}")
            self._last_status = state

    def _log_repeat(self, line: tuple[str, dict[str, Any]] | None) -> None:
        if line is not None:
            name, fields = line
            level = "info" if name.endswith("_recovered") else "warning"
            getattr(self.log, level)(name, **fields)
            if level == "warning":
                self.status_board.alarm(name, level, fields)

    def _log_events(self, events: list[Event]) -> None:
        for ev in events:
            if ev.name == "write_failed":  # once, then a summary a minute (an outage)
                self._log_repeat(self._write_failures.failed(self.clock(), dict(ev.fields)))
                continue
            if ev.name == "probe_refused":  # likewise: a counter may step every cycle
                self._log_repeat(self._probe_refusals.failed(self.clock(), dict(ev.fields)))
                continue
            if ev.name == "probe_accepted":  # ends a run of refusals (probe_refused_recovered)
                self._log_repeat(self._probe_refusals.succeeded(self.clock()))
            level = "warning" if ev.name in _WARNINGS else "info"
            if ev.name in _ERRORS:
                level = "error"
            getattr(self.log, level)(ev.name, **ev.fields)
            if level != "info":
                self.status_board.alarm(ev.name, level, ev.fields)


_WARNINGS = frozenset({"channel_invalid", "fault_hold", "readback_mismatch", "write_failed",
                       "offset_write_skipped", "checkpoint_unusable", "checkpoint_state_refused",
                       "model_non_finite", "probe_refused", "adaptation_state_refused",
                       "adaptation_stood_down", "controller_off"})


def _controller_off(got: Mapping[str, Sample]) -> str | None:
    """Why the controller takes no offset now, from [output] estop and machine_on
    as read (`compd.core.cycle`); None when it does or it cannot be told."""
    def bit(name: str) -> bool | None:
        s = got.get(name)
        if s is None or s.quality is Quality.BAD or not math.isfinite(s.value):
            return None
        return s.value != 0.0

    if bit("estop"):
        return "estop"
    if bit("machine_on") is False:
        return "machine_off"
    return None


def _probe_reading(got: dict[str, Sample]) -> ProbeReading:
    """The probe's value and counter as read (NaN where a read was bad or missing)."""
    def value(name: str) -> float:
        s = got.get(name)
        return float(s.value) if s is not None and s.quality is not Quality.BAD else math.nan

    return ProbeReading(value_um=value(PROBE_NAMES[0]), counter=value(PROBE_NAMES[1]))
_ERRORS = frozenset({"fault_ramp_to_zero", "offset_write_stopped", "output_write_stopped",
                     "readback_out_of_range", "write_fault", "model_out_of_range",
                     "model_worse_than_none"})
