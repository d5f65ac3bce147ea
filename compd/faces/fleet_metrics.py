"""One /metrics endpoint for a process serving several machines (`compd run DIR`).

Each machine's daemon keeps its own `Metrics` (its own registry, as when it
runs alone); `FleetCollector` serves them all on the process's one port, every
sample with a ``machine`` label (``[machine] name``), one family per metric
name. The process's own series (``compd_machine_restarts_total``,
``compd_machine_running``) carry the same label.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping

from prometheus_client import CollectorRegistry, Counter, Gauge
from prometheus_client.metrics_core import Metric
from prometheus_client.registry import Collector

from compd.faces.telemetry import Metrics, MetricsServer

__all__ = ["FleetCollector", "FleetMetrics"]


class FleetCollector(Collector):
    """Every machine's registry, merged, each sample labelled ``machine``."""

    def __init__(self, machines: Callable[[], Mapping[str, Metrics]]) -> None:
        self._machines = machines

    def describe(self) -> list[Metric]:
        return []  # the names are only known when collecting (machines restart)

    def collect(self) -> Iterable[Metric]:
        families: dict[str, Metric] = {}
        for machine, metrics in sorted(self._machines().items()):
            for family in metrics.registry.collect():
                merged = families.get(family.name)
                if merged is None:
                    merged = families[family.name] = Metric(
                        family.name, family.documentation, family.type, family.unit)
                for s in family.samples:
                    merged.add_sample(s.name, {**s.labels, "machine": machine}, s.value,
                                      s.timestamp, s.exemplar)
        return list(families.values())


class FleetMetrics(MetricsServer):
    """The process's registry: the machines' metrics and its own per-machine series."""

    def __init__(self, machines: Callable[[], Mapping[str, Metrics]]) -> None:
        self.registry = CollectorRegistry()
        self.registry.register(FleetCollector(machines))
        self.restarts = Counter("compd_machine_restarts",
                                "Times a machine's daemon task was restarted after a crash",
                                ["machine"], registry=self.registry)
        self.running = Gauge("compd_machine_running",
                             "1 while the machine's daemon task runs, 0 while it waits "
                             "to be restarted", ["machine"], registry=self.registry)
        self._init_server()
