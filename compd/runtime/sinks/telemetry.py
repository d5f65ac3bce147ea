"""Telemetry as a sink: the cycle's Prometheus metrics, systemd's sd_notify,
and the count of complete cycles (the health evidence).

Each cycle: the offset, the fault state and the cause (why the offset compd
wants is not in force, or that it is: `compd.core.health.Cause`, what `compd
health --url` judges), the model's output, each channel's value, invalid
channels counted as read errors, the adaptation estimator's state; a complete
cycle (the report's `in_force`) is counted, at the cycle's own time (its wall-
clock and monotonic seconds, read once by the loop). READY=1 after the loop's
first cycle, whatever that cycle read: the daemon is up, connected or retrying
with its backoff (a controller that is off when the PC boots, or a broken
sensor at start, is a state the fault policy and health report, not a start
failure: waiting for the controller before READY ended in systemd's start
timeout and a restart loop); WATCHDOG=1 every cycle from then on; STATUS= on a
state change or every `STATUS_EVERY` cycles, naming why nothing is in force
while it is not (`compd.core.health.Cause`: ``controller_not_answering`` for a
controller that is off).

`open` labels the metrics for the config and, when this daemon serves its own
endpoint (`serve`; `compd run DIR` serves every machine's registry on one),
starts the HTTP server with the operator page beside /metrics. A port that
cannot be bound is logged (``metrics_unavailable``) and compensation runs
without it.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from typing import TYPE_CHECKING

from compd import __version__
from compd.faces.http_server import limits_from
from compd.faces.logs import logs_at
from compd.runtime.sinks.base import CycleSink, Tick

if TYPE_CHECKING:
    from compd.config.loader import LoadedConfig
    from compd.faces.status import StatusBoard
    from compd.faces.telemetry import Metrics, WSGIApp
    from compd.runtime.journal import Journal
    from compd.runtime.reload import Changes
    from compd.runtime.sdnotify import Notifier

__all__ = ["STATUS_EVERY", "TelemetrySink"]

#: STATUS= is sent on a state change or at least this often (cycles)
STATUS_EVERY = 10


class TelemetrySink(CycleSink):
    stage = "telemetry"

    def __init__(self, *, metrics: Metrics, notifier: Notifier, board: StatusBoard,
                 journal: Journal, serve: bool) -> None:
        self.metrics = metrics
        self.notifier = notifier
        self._board = board
        self._journal = journal
        self._serve = serve
        self.complete_cycles = 0
        self._ready_sent = False
        self._last_status = ""

    async def open(self, cfg: LoadedConfig) -> None:
        self.configure(cfg)
        self.start_http(cfg)

    def configure(self, cfg: LoadedConfig) -> None:
        self.metrics.configure({n: ch.unit for n, ch in cfg.raw.channels.items()},
                               list(cfg.outputs), version=__version__,
                               model_sha256=cfg.model_sha256, config_sha256=cfg.config_sha256)
        self.metrics.period_seconds.set(cfg.real_period_s)

    def start_http(self, cfg: LoadedConfig) -> None:
        if not self._serve:
            return
        tel = cfg.raw.telemetry
        if tel.metrics_port is None:
            if cfg.raw.faces.http.enabled:
                self._journal.log.warning(
                    "status_page_unavailable",
                    reason="[faces.http] is served beside /metrics: it needs [telemetry] "
                           "metrics_port")
            return
        try:
            self.metrics.start_http(tel.metrics_port, tel.metrics_host, self._status_pages(cfg),
                                    limits_from(tel))
        except OSError as exc:  # a port in use: compensation never stops for telemetry
            self._journal.log.error(
                "metrics_unavailable", host=tel.metrics_host, port=tel.metrics_port,
                error=str(exc), hint="compd health --url will report unhealthy; free the "
                                     "port or change telemetry.metrics_port")

    def _status_pages(self, cfg: LoadedConfig) -> Callable[[WSGIApp], WSGIApp] | None:
        """The operator page's wrapper of the metrics app, None without [faces.http]."""
        http = cfg.raw.faces.http
        if not http.enabled:
            return None
        from compd.faces.status_http import daemon_document, with_status

        board = self._board
        board.history_h, board.refresh_s = http.history_h, http.refresh_s  # a reload
        return with_status(lambda history: daemon_document(board, history=history),
                           lambda: board.refresh_s)

    def reload(self, cfg: LoadedConfig, changes: Changes) -> None:
        if changes.metrics:
            self.metrics.stop()
            self.start_http(cfg)
        self.configure(cfg)

    async def close(self) -> None:
        self.notifier.stopping()
        self.metrics.stop()

    def feed(self, tick: Tick) -> None:
        result, m = tick.row, self.metrics
        m.cycle_values(result.stage_um, result.confirmed_um, result.state.gauge)
        m.cause(result.cause)
        m.fallback(result.snapshot.fallback_for)
        m.model_output(result.model_um, result.validity)
        m.axes(result.axes)
        if tick.samples:
            for name, s in tick.samples.items():
                if math.isfinite(s.value):
                    m.channel(name, s.value)
        for name, reason in result.validity.items():
            if reason is not None and reason != "read_failed":
                m.read_errors.labels(channel=name).inc()
        if logs_at(logging.DEBUG):  # not built at all at info (each cycle of each machine)
            self._journal.log.debug("cycle", sequence=result.sequence, state=result.state,
                                    offset_um=round(result.stage_um, 4),
                                    model_um=result.model_um, shadow_um=result.shadow_um,
                                    status=result.status)
        if result.in_force:  # complete (compd.core.cycle.offset_in_force): what the
            # model asks for is in force (never a held, faulted or unconfirmed offset)
            self.complete_cycles += 1
            m.cycle_complete(result.wall_s, tick.mono_s)
        self._notify(tick)
        est = result.snapshot.adaptation
        if est is not None:
            m.adaptation(est.bias_um, est.bias_sigma_um, est.correction_um,
                         result.probe, est.standing_down, est.model_worse,
                         est.guard_worse)

    def _notify(self, tick: Tick) -> None:
        result = tick.row
        if not self._ready_sent:
            # up: the loop runs (the controller answering or the driver retrying)
            self.notifier.ready()
            self._ready_sent = True
            self._journal.log.info("ready", sequence=result.sequence,
                                   offset_um=round(result.stage_um, 4),
                                   inputs_valid=result.inputs_valid,
                                   controller_answers=bool(tick.read_ok),
                                   cause=str(result.cause))
        if self._ready_sent:  # always, from the first cycle
            # the loop is alive: systemd restarting us would not mend a sensor or a link,
            # and a restart would reset the fault policy's hold timer (never ramping)
            self.notifier.watchdog()
        state = str(result.state)
        snap = result.snapshot
        if not result.healthy:
            state += f" ({result.cause})"
        elif snap.fallback_for is not None:
            state += f" (degraded: fallback without {snap.fallback_for})"
        elif snap.pending_um is not None:
            state += f" ({result.cause}, {snap.pending_um:+.2f} um pending)"
        if state != self._last_status or result.sequence % STATUS_EVERY == 0:
            start = f", model {snap.model_start}, reference {snap.reference}" \
                if snap.model_start else ""
            self.notifier.status(f"offset {result.stage_um:.2f} um, state {state}{start}")
            self._last_status = state

