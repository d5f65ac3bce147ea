"""The bounds of the faces' HTTP server (`compd.faces.http_server.HttpServer`):
what one client may hold of it (`HttpLimits`, set by ``[telemetry]``:
`limits_from`), and how hitting one is counted and logged (`LimitCounter`).

Bounds, each counted (`HttpServer.counts`, by reason: `REASONS`) and logged at most once a
minute per reason, never as a traceback:

- ``header_timeout``: a request head (and its small body) must arrive whole
  within `header_timeout_s` of the connection's accept, or of its first byte
  after a kept-alive answer; the connection is then closed (slowloris).
- ``idle_timeout``: a kept-alive connection with no new request for
  `idle_timeout_s` is closed; so is one whose client does not read an answer
  within that time.
- ``evicted`` / ``refused``: at most `max_connections` open connections. A new
  one beyond that closes the connection that has waited longest for a
  request head (idle or slow), so that a scrape still gets in while sockets
  that send nothing fill the cap; when every connection is busy being
  answered, the new one gets 503 and is closed.
- ``head_too_large`` (414 for the request line, 431), ``bad_request`` (400),
  ``body_too_large`` (413), ``not_implemented`` (501, Transfer-Encoding):
  answered and closed.
- ``accept_failed`` (out of file descriptors, EMFILE): accepting pauses for a
  moment instead of spinning, the oldest waiting connection is closed.
- ``app_error``: the application raised; the client gets 500.
- ``write_failed``: the client's socket refused an answer; ``server_error``:
  the I/O thread's own step raised (it goes on).
"""

from __future__ import annotations

import contextlib
import errno
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import structlog

from compd.config.schema import TelemetrySection

__all__ = ["ACCEPT_BATCH", "ACCEPT_OUT_OF_RESOURCES", "ACCEPT_PAUSE_S", "BACKLOG", "LOG_EVERY_S",
           "REASONS", "HttpLimits", "LimitCounter", "limits_from"]

#: every reason a connection is closed early or answered with an error, as counted
REASONS = ("header_timeout", "idle_timeout", "evicted", "refused", "head_too_large",
           "bad_request", "body_too_large", "not_implemented", "accept_failed", "app_error",
           "write_failed", "server_error")

#: seconds between two log lines of one reason (the rest are counted in the next one)
LOG_EVERY_S = 60.0
#: how long accepting pauses after the process ran out of file descriptors
ACCEPT_PAUSE_S = 0.25
#: what accept() says when the process is out of descriptors or memory: accept_failed
ACCEPT_OUT_OF_RESOURCES = frozenset({errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM})
#: connections accepted per wake-up of the loop (the rest wait in the kernel's queue)
ACCEPT_BATCH = 64
#: the listening socket's backlog: deep enough that a flood of connects does not make
#: the kernel drop a scrape's SYN (a retry a second later), the kernel caps it (somaxconn)
BACKLOG = 1024


@dataclass(frozen=True)
class HttpLimits:
    """What one client may hold of the server (see the module docstring)."""

    max_connections: int = 64
    header_timeout_s: float = 5.0
    idle_timeout_s: float = 30.0
    max_head_bytes: int = 16384
    workers: int = 2

    def __post_init__(self) -> None:
        if self.max_connections < 1 or self.workers < 1 or self.max_head_bytes < 256:
            raise ValueError(f"bad HTTP limits: {self}")
        if not (self.header_timeout_s > 0.0 and self.idle_timeout_s > 0.0):
            raise ValueError(f"bad HTTP limits: {self}")


def limits_from(telemetry: TelemetrySection) -> HttpLimits:
    """The bounds ``[telemetry]`` sets (``metrics_max_connections``, ...)."""
    return HttpLimits(max_connections=telemetry.metrics_max_connections,
                      header_timeout_s=telemetry.metrics_header_timeout_s,
                      idle_timeout_s=telemetry.metrics_idle_timeout_s)


class LimitCounter:
    """Counts each reason; logs ``http_connection_limited`` at most once per
    `LOG_EVERY_S` per reason (the next line says how many came between)."""

    def __init__(self, clock: Callable[[], float],
                 on_count: Callable[[str], None] | None = None) -> None:
        self.clock = clock
        self._on_count = on_count
        self.counts: dict[str, int] = dict.fromkeys(REASONS, 0)
        self.log = structlog.get_logger("compd")
        self._logged_at: dict[str, float] = {}
        self._held: dict[str, int] = {}

    def count(self, reason: str, peer: str = "", *, open_connections: int,
              **detail: Any) -> None:
        self.counts[reason] = self.counts.get(reason, 0) + 1
        if self._on_count is not None:
            with contextlib.suppress(Exception):
                self._on_count(reason)
        now = self.clock()
        last = self._logged_at.get(reason)
        if last is not None and now - last < LOG_EVERY_S:
            self._held[reason] = self._held.get(reason, 0) + 1
            return
        self._logged_at[reason] = now
        held = self._held.pop(reason, 0)
        with contextlib.suppress(Exception):  # a log line must not end the I/O thread
            self.log.warning("http_connection_limited", reason=reason, peer=peer,
                             open_connections=open_connections, more_since_last=held,
                             **detail)
