"""What the OPC UA face's guard tells beside its own log lines: its counts as Prometheus
metrics (`GuardCollector`), and asyncua's own line for a refusal the guard has logged
already dropped (`QuietFaults`)."""

from __future__ import annotations

import logging
from collections.abc import Iterator, Mapping

from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector

from compd.faces.opcua_limits import CONNECTION, Guard


class QuietFaults(logging.Filter):
    """Drops asyncua's "sending service fault response" line for a refusal the
    face has logged itself (a failed login, a session over the limit)."""

    def filter(self, record: logging.LogRecord) -> bool:
        conn = CONNECTION.get()
        if conn is None or not conn.quiet_fault:
            return True
        if str(record.msg).startswith("sending service fault"):
            conn.quiet_fault = False
            return False
        return True


_QUIET = QuietFaults()


def quiet_asyncua_faults() -> None:
    """Install `QuietFaults` on asyncua's server processor logger (once)."""
    logger = logging.getLogger("asyncua.server.uaprocessor")
    if _QUIET not in logger.filters:
        logger.addFilter(_QUIET)


class GuardCollector(Collector):
    """The face's counts as Prometheus metrics."""

    def __init__(self, guard: Guard) -> None:
        self.guard = guard

    def collect(self) -> Iterator[Metric]:
        g = self.guard
        yield GaugeMetricFamily("compd_opcua_face_connections",
                                "TCP connections the OPC UA face holds now",
                                value=len(g.connections))
        yield GaugeMetricFamily("compd_opcua_face_connection_limit",
                                "Connections the OPC UA face accepts at most (max_connections, "
                                "lowered to the file descriptors there are)", value=g.limit)
        yield _by_reason(
            "compd_opcua_face_connections_refused",
            "Connections the OPC UA face closed: over the limit (the new one), evicted "
            "to make room for a new one, or no session in time", g.refused)
        yield CounterMetricFamily("compd_opcua_face_logins_failed",
                                  "Logins refused by the OPC UA face (wrong user or password)",
                                  value=g.tallies["opcua_login_failed"].total)
        yield _by_reason(
            "compd_opcua_face_sessions_refused",
            "Sessions refused by the OPC UA face: max_sessions reached, or the anonymous "
            "share (max_sessions minus reserved_sessions) full", g.sessions_refused)


def _by_reason(name: str, documentation: str, counts: Mapping[str, int]
               ) -> CounterMetricFamily:
    """A counter labelled by reason, one sample a reason in `counts`, sorted."""
    family = CounterMetricFamily(name, documentation, labels=["reason"])
    for reason, n in sorted(counts.items()):
        family.add_metric([reason], n)
    return family

