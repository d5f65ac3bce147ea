"""Logging and metrics.

Logging (structlog): JSON lines when stderr is not a terminal (journald, a
container, a file), readable key=value lines on one. Events are names
(``cycle_overrun``, ``controller_reconnected``), not sentences; the details
go in keys. No secret reaches a log line: values of keys that name a secret
(password, secret, token, credential, ...) become ``***``, and every string
registered with `register_secret` (the controller password the daemon
loaded) is replaced by ``***`` wherever it appears in any value, exception
text included. Records of the standard `logging` module (the protocol
libraries log there) go through the same chain; those libraries log at
WARNING and above by default (pymodbus CRITICAL), `[telemetry]
library_log_level` otherwise.

Under systemd (``$JOURNAL_STREAM`` names the device:inode of our stderr) each
line starts with the sd-daemon priority prefix (``<4>`` warning, ``<3>``
error, ...), so that journald files it at its level and ``journalctl -p
warning`` shows compd's warnings.

Metrics (prometheus-client): one `Metrics` per daemon with its own registry,
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
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import re
import sys
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any, TextIO, cast

import structlog
from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, Info
from prometheus_client.exposition import make_wsgi_app
from structlog.typing import EventDict, Processor, WrappedLogger

from compd.config.urls import redact_urls
from compd.core.health import Cause
from compd.faces.http_server import REASONS, HttpLimits, HttpServer, WSGIApp

__all__ = ["REDACTED", "HttpLimits", "LogStream", "Metrics", "WSGIApp", "clear_secrets",
           "configure_logging", "redact", "register_secret"]

REDACTED = "***"
_SECRET_KEY = re.compile(
    r"password|passwd|passphrase|secret|token|credential|api_?key|private_?key", re.IGNORECASE)
#: structlog's bookkeeping for stdlib records: left alone (removed before rendering)
_META_KEYS = frozenset({"_record", "_from_structlog"})
_secrets: set[str] = set()
_secrets_lock = threading.Lock()
_secrets_pattern: re.Pattern[str] | None = None


def register_secret(value: str) -> None:
    """Redact `value` wherever it appears in a log line from now on (empty: ignored)."""
    global _secrets_pattern  # noqa: PLW0603 - one registry per process, by design
    if not value:
        return
    with _secrets_lock:
        _secrets.add(value)
        # longest first, so that a secret containing another is replaced whole
        alternatives = sorted(_secrets, key=len, reverse=True)
        _secrets_pattern = re.compile("|".join(re.escape(s) for s in alternatives))


def clear_secrets() -> None:
    """Forget every registered secret (for tests)."""
    global _secrets_pattern  # noqa: PLW0603
    with _secrets_lock:
        _secrets.clear()
        _secrets_pattern = None


def _scrub(value: Any, pattern: re.Pattern[str] | None) -> Any:
    if isinstance(value, str):
        value = redact_urls(value)  # user:password@ in any URL, registered or not
        return pattern.sub(REDACTED, value) if pattern is not None else value
    if value is None or isinstance(value, bool | int | float):
        return value
    if isinstance(value, Mapping):
        return {k: (REDACTED if isinstance(k, str) and _SECRET_KEY.search(k)
                    else _scrub(v, pattern)) for k, v in value.items()}
    if isinstance(value, list | tuple | set | frozenset):
        return [_scrub(v, pattern) for v in value]
    text = str(value)  # an object whose text may carry a secret (an exception, a URL)
    scrubbed = redact_urls(text)
    if pattern is not None:
        scrubbed = pattern.sub(REDACTED, scrubbed)
    return scrubbed if scrubbed != text else value


def redact(_logger: WrappedLogger, _name: str, event_dict: EventDict) -> EventDict:
    """structlog processor: hide secret-named keys and registered secret strings."""
    pattern = _secrets_pattern
    for key in list(event_dict):
        if key in _META_KEYS:
            continue
        if _SECRET_KEY.search(key):
            event_dict[key] = REDACTED
        else:
            event_dict[key] = _scrub(event_dict[key], pattern)
    return event_dict


class LogStream:
    """The stream log lines go to, made safe for the daemon: a line that cannot
    be written (a full disk under a log file, a closed pipe) is dropped and
    counted in `dropped_lines`, never raised into the compensation loop.

    Each line reaches the stream whole, in one write and a flush: the text of a
    line is held until its newline (`print` writes a message and its end
    apart). Processes that share one stderr (`compd run DIR --workers N`: the
    parent and its workers) then never splice one line into another."""

    def __init__(self, stream: TextIO) -> None:
        self.stream = stream
        self.dropped_lines = 0
        self._pending = ""

    def write(self, text: str) -> int:
        taken = len(text)
        text = self._pending + text
        head, newline, self._pending = text.rpartition("\n")
        if newline:
            try:
                self.stream.write(head + newline)
                self.stream.flush()
            except (OSError, ValueError):  # ENOSPC, EIO, EPIPE; ValueError: closed
                self.dropped_lines += 1
        return taken

    def flush(self) -> None:
        if self._pending:  # a line without its newline yet: written as it is
            text, self._pending = self._pending, ""
            try:
                self.stream.write(text)
            except (OSError, ValueError):
                self.dropped_lines += 1
        try:
            self.stream.flush()
        except (OSError, ValueError):
            self.dropped_lines += 1

    def isatty(self) -> bool:
        try:
            return self.stream.isatty()
        except (OSError, ValueError):
            return False


#: The least level the protocol libraries log at (whatever the daemon's level),
#: unless `[telemetry] library_log_level` says otherwise.
LIBRARY_LOG_FLOOR = {"asyncua": logging.WARNING, "snap7": logging.WARNING,
                     "pymodbus": logging.CRITICAL}

#: sd-daemon(3) priority prefixes by structlog level name
SD_PRIORITY = {"critical": 2, "exception": 3, "error": 3, "warning": 4, "warn": 4,
               "notice": 5, "info": 6, "debug": 7}


def is_journal_stream(stream: TextIO, env: Mapping[str, str] | None = None) -> bool:
    """True when `stream` is the journal's stream socket: $JOURNAL_STREAM
    ("device:inode", set by systemd) matches the stream's file."""
    value = (os.environ if env is None else env).get("JOURNAL_STREAM", "")
    dev, _, ino = value.partition(":")
    if not (dev.isdigit() and ino.isdigit()):
        return False
    try:
        st = os.fstat(stream.fileno())
    except (OSError, ValueError, AttributeError):  # closed, or not a file (io.StringIO)
        return False
    return (st.st_dev, st.st_ino) == (int(dev), int(ino))


def _with_priority(renderer: Processor) -> Processor:
    """`renderer`, each line prefixed with its sd-daemon ``<N>`` priority."""
    def render(logger: WrappedLogger, name: str, event_dict: EventDict) -> Any:
        level = str(event_dict.get("level", name)).lower()
        line = renderer(logger, name, event_dict)
        prefix = f"<{SD_PRIORITY.get(level, 6)}>"
        return prefix.encode() + line if isinstance(line, bytes) else prefix + str(line)
    return render


def library_floors(level: str = "default") -> dict[str, int]:
    """The least level of each protocol library's logger (`library_log_level`)."""
    if level == "default":
        return dict(LIBRARY_LOG_FLOOR)
    levelno = logging.getLevelNamesMapping()[level.upper()]
    return dict.fromkeys(LIBRARY_LOG_FLOOR, levelno)


def configure_logging(json: bool | None = None, level: str = "info", *,
                      stream: TextIO | None = None, library_level: str = "default",
                      journal: bool | None = None) -> None:
    """Set up structlog (and the stdlib root logger) for the daemon.

    `json`: True JSON lines, False key=value, None decide by ``stream.isatty()``.
    `level`: debug, info, warning, error or critical. `stream`: where lines go,
    sys.stderr (looked up at call time) by default. `library_level`: see
    `library_floors`. `journal`: prefix the sd-daemon priority; None: when
    `is_journal_stream(stream)`.
    """
    target = stream if stream is not None else sys.stderr
    out = LogStream(target)
    if journal is None:
        journal = is_journal_stream(target)
    levelno = logging.getLevelNamesMapping().get(level.upper())
    if levelno is None:
        raise ValueError(f"unknown log level {level!r}")
    as_json = (not out.isatty()) if json is None else json
    shared: list[Processor] = [
        structlog.contextvars.merge_contextvars,
        structlog.processors.add_log_level,
        structlog.processors.TimeStamper(fmt="iso", utc=True),
        structlog.processors.StackInfoRenderer(),
        structlog.processors.format_exc_info,  # exception text, so that it is redacted too
        redact,
    ]
    renderer: Processor
    if as_json:
        renderer = structlog.processors.JSONRenderer(sort_keys=False)
    else:
        renderer = structlog.dev.ConsoleRenderer(colors=False)
    if journal:
        renderer = _with_priority(renderer)
    structlog.configure(
        processors=[*shared, renderer],
        wrapper_class=structlog.make_filtering_bound_logger(levelno),
        logger_factory=structlog.PrintLoggerFactory(file=cast(TextIO, out)),
        cache_logger_on_first_use=False,
    )
    # the protocol libraries log through `logging`: same format, same redaction
    handler = logging.StreamHandler(out)
    handler.setFormatter(structlog.stdlib.ProcessorFormatter(
        foreign_pre_chain=[structlog.stdlib.add_logger_name, *shared],
        processors=[structlog.stdlib.ProcessorFormatter.remove_processors_meta, renderer],
    ))
    handler.set_name("compd")
    root = logging.getLogger()
    for old in [h for h in root.handlers if h.get_name() == "compd"]:
        root.removeHandler(old)
    root.addHandler(handler)
    root.setLevel(levelno)
    # the libraries report what our drivers report again (a failed request is one
    # read_failed/write_failed line of ours): their INFO is noise (asyncua dumps 6 KB of
    # endpoints on every connect) and pymodbus logs each failed frame as an ERROR hex dump
    for name, floor in library_floors(library_level).items():
        logging.getLogger(name).setLevel(max(levelno, floor) if library_level == "default"
                                         else floor)


#: what ``compd_offset_micrometres`` is: the cycle report's ``stage_um``
OFFSET_HELP = ("The output stage's offset this cycle (the cycle report's stage_um: after "
               "limit, slew limit and fault policy), in micrometres, sent whether or not "
               "the controller took it: a failed write leaves the controller on its last "
               "confirmed offset, compd_offset_confirmed_micrometres")


#: what ``compd_offset_confirmed_micrometres`` is: the cycle report's ``confirmed_um``
CONFIRMED_HELP = ("Offset the controller last confirmed holding (the cycle report's "
                  "confirmed_um: read back or acknowledged), in micrometres; NaN while "
                  "unknown (before the first confirmed write)")


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
        #: (`labels()` hashes and locks on every call: twice a channel a cycle before)
        self._value_series: dict[str, Gauge] = {}
        self._valid_series: dict[str, Gauge] = {}
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
        self._fallback: str | None = None
        self._cause: Cause | None = None
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

    @staticmethod
    def _remove(metric: Gauge, *labels: str) -> None:
        with contextlib.suppress(KeyError):
            metric.remove(*labels)

    def channel(self, name: str, value: float) -> None:
        """The last value of channel `name` (degC and K to °C; others as read)."""
        series = self._value_series.get(name)
        unit = self._channel_units.get(name, "")
        if series is None:
            series = (self.channel_temperature.labels(channel=name) if unit in ("degC", "K")
                      else self.channel_value.labels(channel=name, unit=unit))
            self._value_series[name] = series
        series.set(value - 273.15 if unit == "K" else value)

    def model_output(self, model_um: float | None,
                     validity: Mapping[str, str | None]) -> None:
        """The model's output this cycle (None: it did not step) and each channel's
        validity (name -> None when valid, else the reason)."""
        self.model_output_um.set(math.nan if model_um is None else model_um)
        for name, reason in validity.items():
            series = self._valid_series.get(name)
            if series is None:
                series = self._valid_series[name] = self.channel_valid.labels(channel=name)
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
