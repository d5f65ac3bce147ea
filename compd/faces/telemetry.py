"""Metrics (prometheus-client): one `Metrics` per daemon with its own registry,
served over HTTP by `Metrics.start_http` (``[telemetry] metrics_host``,
127.0.0.1 by default) from a bounded server with a fixed number of threads
(`compd.faces.http_server`). Names follow Prometheus' naming practice: base units
(seconds, degrees Celsius), one unit per metric, ``_total`` counters, an info
metric. The one exception, chosen and documented (docs/operation.md §10): the
offset is in micrometres (``compd_offset_micrometres``), the unit the
machine, the model and every log line use; 1.2e-05 metres would say less.
Labelled counters are created at zero for every configured channel and
output (`Metrics.configure`), so that ``rate()`` and ``increase()`` see the
first error.

The logging set-up is `compd.faces.logs`; its names are importable from here too.
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Callable, Mapping
from typing import Any

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, Info
from prometheus_client.exposition import make_wsgi_app

from compd.core.axis_params import AxisRow
from compd.core.health import Cause
from compd.faces.http_server import REASONS, HttpLimits, HttpServer, WSGIApp
from compd.faces.logs import (
    LIBRARY_LOG_FLOOR,
    REDACTED,
    LogStream,
    clear_secrets,
    configure_logging,
    is_journal_stream,
    redact,
    register_secret,
)

__all__ = ["LIBRARY_LOG_FLOOR", "REDACTED", "HttpLimits", "LogStream", "Metrics", "WSGIApp",
           "clear_secrets", "configure_logging", "is_journal_stream", "redact",
           "register_secret"]

#: what ``compd_offset_micrometres`` is: the cycle report's ``stage_um``
OFFSET_HELP = ("The output stage's offset this cycle (the cycle report's stage_um: after "
               "limit, slew limit and fault policy), in micrometres, sent whether or not "
               "the controller took it: a failed write leaves the controller on its last "
               "confirmed offset, compd_offset_confirmed_micrometres")


#: what ``compd_offset_confirmed_micrometres`` is: the cycle report's ``confirmed_um``
CONFIRMED_HELP = ("Offset the controller last confirmed holding (the cycle report's "
                  "confirmed_um: read back or acknowledged), in micrometres; NaN while "
                  "unknown (before the first confirmed write)")


class _Last:
    """One series (a gauge, or one labelled series of it) and the value it was last
    set to: set only when the value changes. A set takes the series' lock and most
    of a cycle's values stay put from one cycle to the next (a temperature read to
    0.1 K, a channel's validity, the fault state), which in a process of a
    thousand machines is a thousand sets a second each."""

    __slots__ = ("gauge", "value")

    def __init__(self, gauge: Gauge) -> None:
        self.gauge = gauge
        self.value: float | None = None  # None: never set

    def set(self, value: float) -> None:
        last = self.value
        if last is not None and (value == last or (math.isnan(value) and math.isnan(last))):
            return  # unchanged (NaN as NaN)
        self.gauge.set(value)
        self.value = value


class _AxisSeries:
    """One axis's four series (value, slope, in force, fault state) and the values
    they were last set to: a series is set when its value changes (a set takes the
    series' lock; an axis's state and in-force flag stay put for hours)."""

    __slots__ = ("gauges", "last")

    def __init__(self, gauges: tuple[Gauge, Gauge, Gauge, Gauge]) -> None:
        self.gauges = gauges
        self.last: tuple[float, ...] = (math.nan,) * len(gauges)  # NaN: never set

    def set(self, values: tuple[float, float, float, float]) -> None:
        if values == self.last:
            return
        for gauge, value, was in zip(self.gauges, values, self.last, strict=True):
            if value != was:
                gauge.set(value)
        self.last = values


class MetricsServer:
    """`registry` served as /metrics by a bounded server (`compd.faces.http_server`):
    `start_http`, `port`, `stop` (for one daemon's `Metrics` and for a fleet
    process's `FleetMetrics`). The server's own counters (``compd_http_*``) join
    the registry when it first serves."""

    registry: CollectorRegistry

    def _init_server(self) -> None:
        self._server: HttpServer | None = None
        self._http_limited: Counter | None = None

    @property
    def port(self) -> int | None:
        """The port served on (useful after `start_http(0)`), None when not serving."""
        return None if self._server is None else self._server.port

    @property
    def http_server(self) -> HttpServer | None:
        """The running server (None when not serving)."""
        return self._server

    def _http_metrics(self) -> Counter:
        if self._http_limited is None:
            r = self.registry
            self._http_limited = Counter(
                "compd_http_limited", "HTTP connections closed or answered with an error "
                "by the server's bounds, by reason (header_timeout, idle_timeout, evicted, "
                "refused, head_too_large, ...)", ["reason"], registry=r)
            for reason in REASONS:
                self._http_limited.labels(reason=reason)
            Gauge("compd_http_connections", "Open HTTP connections to /metrics and the "
                  "status page", registry=r).set_function(
                lambda: float(self._server.open_connections) if self._server else 0.0)
        return self._http_limited

    def start_http(self, port: int, host: str = "127.0.0.1",
                   wrap: Callable[[WSGIApp], WSGIApp] | None = None,
                   limits: HttpLimits | None = None) -> None:
        """Serve /metrics on host:port (port 0: a free port, see `port`) with a fixed
        number of threads. `wrap`: wraps the metrics WSGI app to serve more paths on
        the same server (the operator page, `compd.faces.status_http`). `limits`:
        connections, timeouts and head size (`HttpLimits` defaults)."""
        if self._server is not None:
            raise RuntimeError(f"metrics already served on port {self.port}")
        app: WSGIApp = make_wsgi_app(self.registry)
        if wrap is not None:
            app = wrap(app)
        limited = self._http_metrics()
        server = HttpServer(app, host, port, limits,
                            on_count=lambda reason: limited.labels(reason=reason).inc())
        server.start()
        self._server = server

    def stop(self) -> None:
        """Stop serving and free the port. Idempotent."""
        server, self._server = self._server, None
        if server is not None:
            server.stop()


class Metrics(MetricsServer):
    """The daemon's Prometheus metrics, in their own registry (`registry`)."""

    def __init__(self, registry: CollectorRegistry | None = None, *,
                 mono: Callable[[], float] = time.monotonic) -> None:
        self.registry = registry if registry is not None else CollectorRegistry()
        #: the monotonic clock the last complete cycle's age is judged on (the daemon's)
        self._mono = mono
        r = self.registry
        self.cycle_seconds = Histogram(
            "compd_cycle_seconds", "Time one cycle took, read to record (s)", registry=r,
            buckets=(0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0,
                     5.0, 10.0))
        self.overruns = Counter("compd_overruns", "Cycles that missed their deadline",
                                registry=r)
        self.read_errors = Counter("compd_read_errors", "Failed or invalid channel reads",
                                   ["channel"], registry=r)
        self.write_errors = Counter("compd_write_errors", "Failed writes to the controller",
                                    ["output"], registry=r)
        #: the output stage's value, not what the controller holds: that is the
        #: confirmed offset (the OPC UA face's Offset_um, the recorder's offset_um)
        self.offset_um = Gauge("compd_offset_micrometres", OFFSET_HELP, registry=r)
        self.confirmed_um = Gauge("compd_offset_confirmed_micrometres", CONFIRMED_HELP,
                                  registry=r)
        self.channel_temperature = Gauge(
            "compd_channel_temperature_celsius",
            "Last value read per temperature channel, in degrees Celsius", ["channel"],
            registry=r)
        self.channel_value = Gauge(
            "compd_channel_value", "Last value read per channel that is not a temperature, "
            "in the channel's configured unit (the unit label)", ["channel", "unit"],
            registry=r)
        self._channel_units: dict[str, str] = {}
        #: each channel's value and validity series, resolved once per configuration
        #: (`labels()` hashes and locks on every call: twice a channel a cycle before),
        #: each set when its value changes
        self._value_series: dict[str, _Last] = {}
        self._valid_series: dict[str, _Last] = {}
        #: axis -> its value, slope, in-force and fault-state series, looked up once,
        #: and the values they were last set to
        self._axis_series: dict[str, _AxisSeries] = {}
        self.build_info = Info("compd_build", "compd's version and the sha256 of the model "
                               "and config it runs", registry=r)
        self.fault_state = Gauge("compd_fault_state",
                                 "Fault state: 0 ok, 1 hold or not yet compensating, 2 ramp, "
                                 "3 alarm/stopped", registry=r)
        self.records_dropped = Counter("compd_records_dropped",
                                       "Samples the recorder could not store", registry=r)
        self.recorder_alarm = Gauge("compd_recorder_alarm",
                                    "1 while the recorder cannot store samples (disk full, "
                                    "I/O error)", registry=r)
        self.certificate_expiry = Gauge(
            "compd_certificate_expiry_timestamp_seconds",
            "When the OPC UA certificate expires (s since the epoch); only where one is "
            "configured", ["role"], registry=r)
        self.cycles_complete = Counter(
            "compd_cycles_complete", "Complete cycles (the cycle report's in_force): inputs "
            "read and valid, model stepped, offset write confirmed by the controller",
            registry=r)
        self.last_complete_timestamp = Gauge(
            "compd_last_complete_cycle_timestamp_seconds",
            "Wall-clock time of the last complete cycle, read once at its start (the cycle "
            "report's wall_s; s since the epoch)", registry=r)
        self._last_complete_mono: float | None = None
        self.last_complete_age = Gauge(
            "compd_last_complete_cycle_age_seconds",
            "Seconds since the last complete cycle, on the monotonic clock (+Inf before "
            "the first): what `compd health --url` judges", registry=r)
        self.last_complete_age.set_function(self._age_s)
        self.model_output_um = Gauge(
            "compd_model_output_micrometres", "The model's output in the last cycle (the "
            "cycle report's model_um), in micrometres, before limits and the fault policy "
            "(NaN when the model did not step)", registry=r)
        self.period_seconds = Gauge(
            "compd_period_seconds", "The sampling period in wall-clock seconds (period_s / "
            "time_scale): what alert rules measure lateness and silence against",
            registry=r)
        self.channel_valid = Gauge(
            "compd_channel_valid", "1 when the channel's last value was valid, 0 when it "
            "was not (read failed, out of range, stale, ...)", ["channel"], registry=r)
        self.adaptation_bias_um = Gauge(
            "compd_adaptation_bias_micrometres", "The probe-assisted adaptation's bias "
            "estimate (what it adds to the model output in apply mode)", registry=r)
        self.adaptation_bias_sigma_um = Gauge(
            "compd_adaptation_bias_sigma_micrometres", "The standard deviation of the "
            "adaptation's bias estimate", registry=r)
        self.adaptation_correction_um = Gauge(
            "compd_adaptation_correction_micrometres", "The correction the adaptation "
            "proposes this cycle (applied only in apply mode)", registry=r)
        self.adaptation_standing_down = Gauge(
            "compd_adaptation_standing_down", "1 while the adaptation stands down: its "
            "score over the last probes says adapting does not beat the plain model, so it "
            "applies nothing", registry=r)
        self.model_worse_than_none = Gauge(
            "compd_model_worse_than_none", "1 once the probes showed the compensation "
            "making the error larger than none would (status bit MODEL_WORSE; held, then "
            "ramped to zero per [faults]) until a restart or reload", registry=r)
        self.probes = Counter(
            "compd_probes", "Probe measurements seen, by outcome (accepted, refused) and "
            "reason (gate: innovation too large; fault: cycle not complete; no_offset)",
            ["outcome", "reason"], registry=r)
        self.guard_worse_probes = Gauge(
            "compd_guard_worse_probes", "Accepted probes in a row that showed the "
            "compensation worse than none (the guard trips at guard_window; refused "
            "probes are never counted)", registry=r)
        self.offset_not_in_force = Gauge(
            "compd_offset_not_in_force", "1 while the offset compd wants is not in force "
            "for any reason but an operator's hold (the compd_output_cause that is 1 "
            "says why): what `compd health --url` judges", registry=r)
        self.output_cause = Gauge(
            "compd_output_cause", "1 for the last cycle's cause (why the offset compd "
            "wants is not in force: in_force, operator_hold, inputs_invalid, "
            "model_worse_than_none, ...), 0 for the others", ["cause"], registry=r)
        self.fallback_in_force = Gauge(
            "compd_fallback_in_force", "1 for the input whose fallback model is in force "
            "(degraded: that sensor is invalid), 0 for the others; all 0: the main model",
            ["lost"], registry=r)
        self.axis_value_um = Gauge(
            "compd_axis_value_micrometres", "Each [output.axes] axis's compensation value at "
            "its reference position, the output stage's (µm)", ["axis"], registry=r)
        self.axis_slope_um_m = Gauge(
            "compd_axis_slope_micrometres_per_metre", "Each [output.axes] axis's "
            "compensation slope, the output stage's (µm/m)", ["axis"], registry=r)
        self.axis_in_force = Gauge(
            "compd_axis_in_force", "1 while the axis's line compd wants is the line in "
            "force (confirmed this cycle), 0 otherwise (compd_axis_fault_state says how)",
            ["axis"], registry=r)
        self.axis_fault_state = Gauge(
            "compd_axis_fault_state", "Each axis's state, as compd_fault_state: 0 ok, "
            "1 hold, 2 ramp, 3 alarm/stopped", ["axis"], registry=r)
        self._fallback: str | None = None
        self._cause: Cause | None = None
        #: the series every cycle sets (`cycle_values`), each set when its value changes
        self._offset = _Last(self.offset_um)
        self._confirmed = _Last(self.confirmed_um)
        self._fault_state = _Last(self.fault_state)
        self._model_output = _Last(self.model_output_um)
        self._init_server()

    def configure(self, channels: Mapping[str, str], outputs: list[str], *, version: str,
                  model_sha256: str, config_sha256: str) -> None:
        """The configured channels (name -> unit) and outputs: their error counters
        exist at zero from the start; the build info names what runs. Called again
        on a reload (series of channels no longer configured are removed)."""
        for name, unit in self._channel_units.items():
            if name not in channels or channels[name] != unit:
                self._remove(self.channel_temperature, name)
                self._remove(self.channel_value, name, unit)
            if name not in channels:
                self._remove(self.channel_valid, name)
        self._channel_units = dict(channels)
        self._value_series.clear()
        self._valid_series.clear()
        for name in channels:
            self.read_errors.labels(channel=name)
        self.read_errors.labels(channel="*")
        for name in outputs:
            self.write_errors.labels(output=name)
        self.build_info.info({"version": version, "model_sha256": model_sha256,
                              "config_sha256": config_sha256})

    def axes(self, rows: Mapping[str, AxisRow]) -> None:
        """Each configured axis's line, in force and state this cycle. An axis no
        longer in the report (a reload without it) loses its series: a stale
        ``compd_axis_in_force`` of 1 would claim a line compd no longer keeps."""
        series = self._axis_series
        if series.keys() != rows.keys():
            for axis in [a for a in series if a not in rows]:
                for metric in (self.axis_value_um, self.axis_slope_um_m, self.axis_in_force,
                               self.axis_fault_state):
                    self._remove(metric, axis)
                del series[axis]
        for axis, row in rows.items():
            got = series.get(axis)
            if got is None:
                got = series[axis] = _AxisSeries((
                    self.axis_value_um.labels(axis=axis), self.axis_slope_um_m.labels(axis=axis),
                    self.axis_in_force.labels(axis=axis), self.axis_fault_state.labels(axis=axis)))
            got.set((row.value.stage, row.slope.stage, 1.0 if row.in_force else 0.0,
                     float(row.state.gauge)))

    @staticmethod
    def _remove(metric: Gauge, *labels: str) -> None:
        with contextlib.suppress(KeyError):
            metric.remove(*labels)

    def cycle_values(self, stage_um: float, confirmed_um: float | None,
                     fault_state: float) -> None:
        """The cycle's offset (the output stage's), the offset the controller confirmed
        (None: unknown) and the fault state's gauge value."""
        self._offset.set(stage_um)
        self._confirmed.set(math.nan if confirmed_um is None else confirmed_um)
        self._fault_state.set(fault_state)

    def channel(self, name: str, value: float) -> None:
        """The last value of channel `name` (degC and K to °C; others as read)."""
        series = self._value_series.get(name)
        unit = self._channel_units.get(name, "")
        if series is None:
            series = self._value_series[name] = _Last(
                self.channel_temperature.labels(channel=name) if unit in ("degC", "K")
                else self.channel_value.labels(channel=name, unit=unit))
        series.set(value - 273.15 if unit == "K" else value)

    def model_output(self, model_um: float | None,
                     validity: Mapping[str, str | None]) -> None:
        """The model's output this cycle (None: it did not step) and each channel's
        validity (name -> None when valid, else the reason)."""
        self._model_output.set(math.nan if model_um is None else model_um)
        for name, reason in validity.items():
            series = self._valid_series.get(name)
            if series is None:
                series = self._valid_series[name] = _Last(self.channel_valid.labels(channel=name))
            series.set(1.0 if reason is None else 0.0)

    def adaptation(self, bias_um: float, bias_sigma_um: float, correction_um: float,
                   probe: Mapping[str, Any] | None, standing_down: bool = False,
                   model_worse: bool = False, guard_worse: int = 0) -> None:
        """The estimator's state this cycle, and the probe that arrived (if one did)."""
        self.guard_worse_probes.set(float(guard_worse))
        self.adaptation_standing_down.set(1.0 if standing_down else 0.0)
        self.model_worse_than_none.set(1.0 if model_worse else 0.0)
        self.adaptation_bias_um.set(bias_um)
        self.adaptation_bias_sigma_um.set(bias_sigma_um)
        self.adaptation_correction_um.set(correction_um)
        if probe is not None:
            outcome = "accepted" if probe.get("accepted") else "refused"
            self.probes.labels(outcome=outcome, reason=str(probe.get("reason") or "")).inc()

    def cause(self, cause: Cause) -> None:
        """The last cycle's cause (`compd.core.health.Cause`): one series at 1."""
        if cause is self._cause:
            return
        for c in Cause:
            self.output_cause.labels(cause=c.value).set(1.0 if c is cause else 0.0)
        self.offset_not_in_force.set(0.0 if cause.healthy else 1.0)
        self._cause = cause

    def fallback(self, lost: str | None) -> None:
        """The input whose fallback model is in force this cycle (None: the main model)."""
        if lost == self._fallback:
            return
        if self._fallback is not None:
            self.fallback_in_force.labels(lost=self._fallback).set(0.0)
        if lost is not None:
            self.fallback_in_force.labels(lost=lost).set(1.0)
        self._fallback = lost

    def _age_s(self) -> float:
        last = self._last_complete_mono
        return math.inf if last is None else max(0.0, self._mono() - last)

    def cycle_complete(self, wall_s: float | None = None, mono_s: float | None = None) -> None:
        """A complete cycle (the report's `in_force`) at `wall_s` and `mono_s` (the
        cycle's time, read once by the daemon's loop; now by default). Its age for
        /health is judged on the same monotonic clock (`mono`), read when a request
        arrives in an HTTP thread."""
        self._last_complete_mono = self._mono() if mono_s is None else mono_s
        self.last_complete_timestamp.set(time.time() if wall_s is None else wall_s)
        self.cycles_complete.inc()
