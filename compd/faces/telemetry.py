"""Logging and metrics.

Logging (structlog): JSON lines when stderr is not a terminal (journald, a
container, a file), readable key=value lines on one. Events are names
(``cycle_overrun``, ``controller_reconnected``), not sentences; the details
go in keys. No secret reaches a log line: values of keys that name a secret
(password, secret, token, credential, ...) become ``***``, and every string
registered with `register_secret` (the controller password the daemon
loaded) is replaced by ``***`` wherever it appears in any value, exception
text included. Records of the standard `logging` module (the protocol
libraries log there) go through the same chain.

Metrics (prometheus-client): one `Metrics` per daemon with its own registry,
served over HTTP by `Metrics.start_http` (127.0.0.1 by default).
"""

from __future__ import annotations

import logging
import re
import sys
import threading
from collections.abc import Mapping
from typing import Any, TextIO, cast
from wsgiref.simple_server import WSGIServer

import structlog
from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram
from prometheus_client.exposition import start_http_server
from structlog.typing import EventDict, Processor, WrappedLogger

__all__ = ["REDACTED", "LogStream", "Metrics", "clear_secrets", "configure_logging", "redact",
           "register_secret"]

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
        return pattern.sub(REDACTED, value) if pattern is not None else value
    if value is None or isinstance(value, bool | int | float):
        return value
    if isinstance(value, Mapping):
        return {k: (REDACTED if isinstance(k, str) and _SECRET_KEY.search(k)
                    else _scrub(v, pattern)) for k, v in value.items()}
    if isinstance(value, list | tuple | set | frozenset):
        return [_scrub(v, pattern) for v in value]
    if pattern is not None:  # an object whose text may carry a secret (an exception, a URL)
        text = str(value)
        if pattern.search(text):
            return pattern.sub(REDACTED, text)
    return value


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
    counted in `dropped_lines`, never raised into the compensation loop."""

    def __init__(self, stream: TextIO) -> None:
        self.stream = stream
        self.dropped_lines = 0

    def write(self, text: str) -> int:
        try:
            return self.stream.write(text)
        except (OSError, ValueError):  # ENOSPC, EIO, EPIPE; ValueError: closed
            self.dropped_lines += 1
            return len(text)

    def flush(self) -> None:
        try:
            self.stream.flush()
        except (OSError, ValueError):
            self.dropped_lines += 1

    def isatty(self) -> bool:
        try:
            return self.stream.isatty()
        except (OSError, ValueError):
            return False


def configure_logging(json: bool | None = None, level: str = "info", *,
                      stream: TextIO | None = None) -> None:
    """Set up structlog (and the stdlib root logger) for the daemon.

    `json`: True JSON lines, False key=value, None decide by ``stream.isatty()``.
    `level`: debug, info, warning, error or critical. `stream`: where lines go,
    sys.stderr (looked up at call time) by default.
    """
    out = LogStream(stream if stream is not None else sys.stderr)
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


class Metrics:
    """The daemon's Prometheus metrics, in their own registry (`registry`)."""

    def __init__(self, registry: CollectorRegistry | None = None) -> None:
        self.registry = registry if registry is not None else CollectorRegistry()
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
        self.offset_um = Gauge("compd_offset_um", "Offset last written (µm)", registry=r)
        self.channel_value = Gauge("compd_channel_value", "Last value read per channel",
                                   ["channel"], registry=r)
        self.fault_state = Gauge("compd_fault_state",
                                 "Fault state: 0 ok, 1 hold, 2 ramp, 3 alarm/stopped", registry=r)
        self.records_dropped = Counter("compd_records_dropped",
                                       "Samples the recorder could not store", registry=r)
        self.recorder_alarm = Gauge("compd_recorder_alarm",
                                    "1 while the recorder cannot store samples (disk full, "
                                    "I/O error)", registry=r)
        self.cert_expiry_days = Gauge("compd_cert_expiry_days",
                                      "Days until the client certificate expires", registry=r)
        self._server: WSGIServer | None = None
        self._thread: threading.Thread | None = None

    @property
    def port(self) -> int | None:
        """The port served on (useful after `start_http(0)`), None when not serving."""
        if self._server is None:
            return None
        return int(self._server.server_address[1])

    def start_http(self, port: int, host: str = "127.0.0.1") -> None:
        """Serve /metrics on host:port (port 0: a free port, see `port`) from a thread."""
        if self._server is not None:
            raise RuntimeError(f"metrics already served on port {self.port}")
        server, thread = start_http_server(port, addr=host, registry=self.registry)
        self._server, self._thread = server, thread

    def stop(self) -> None:
        """Stop serving and free the port. Idempotent."""
        server, thread = self._server, self._thread
        self._server = self._thread = None
        if server is not None:
            server.shutdown()
            server.server_close()
        if thread is not None:
            thread.join(timeout=5.0)
