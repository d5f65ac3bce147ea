"""One /metrics and one status page for `compd run DIR --workers N`.

Each worker process serves its machines' metrics and status exactly as `compd
run DIR` in one process does (`compd.faces.fleet_metrics`: every series with
its ``machine`` label), on a loopback port of its own that only the parent
reads. The parent's endpoint (the files' ``[telemetry] metrics_port``) answers
for all of them:

- ``/metrics``: the workers' expositions fetched at the scrape (concurrently,
  each within `FETCH_TIMEOUT_S`) and merged by family name: one ``# HELP`` and
  ``# TYPE`` per family, then the samples of every worker. Machine names are
  unique across the directory, so every series stays unique. The parent's own
  series join them: ``compd_worker_running{worker}``,
  ``compd_worker_restarts_total{worker}``, its server's ``compd_http_*`` (the
  workers' own ``compd_http_*``, about the loopback link, are left out), and
  ``compd_machine_running{machine} 0`` for each machine of a worker that is
  down or did not answer (its other series are then absent until it answers).
  Text format 0.0.4, gzip when the client accepts it.
- ``/`` and ``/status.json`` (``[faces.http]`` in any file): the workers'
  documents joined into one, sorted by machine; a machine whose worker is down
  shows as ``off``, "its worker process is restarting".

prometheus_client's multiprocess mode was not used: it does not carry the
custom collectors and callback gauges the daemon's registry has, and it would
move every metric update onto shared files.
"""

from __future__ import annotations

import gzip
import json
import urllib.request
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

from prometheus_client import CollectorRegistry, Counter, Gauge, generate_latest
from prometheus_client.exposition import CONTENT_TYPE_LATEST

from compd.faces.http_server import HttpLimits
from compd.faces.status_http import FLEET_HISTORY_MAX, with_status
from compd.faces.telemetry import MetricsServer, WSGIApp

__all__ = ["FETCH_TIMEOUT_S", "PoolMetrics", "WorkerView", "merge_expositions"]

#: how long the parent waits for one worker's answer during a scrape
FETCH_TIMEOUT_S = 10.0
#: the families each process has of its own (its HTTP server's): the parent's are served
WORKER_PRIVATE = frozenset({"compd_http_limited", "compd_http_connections"})


@dataclass(frozen=True)
class WorkerView:
    """What the parent knows of one worker at a scrape: its machines, and the
    loopback port it answers on (None while it is down or starting)."""

    index: int
    machines: tuple[str, ...]
    port: int | None
    #: its machines with [faces.http] (its status document lists only these)
    paged: tuple[str, ...] = ()


def merge_expositions(bodies: Iterable[str], drop: frozenset[str] = frozenset()) -> str:
    """Prometheus text expositions (0.0.4) merged by family: each family's HELP and
    TYPE once, then its samples from every body in order; families named in
    `drop` left out."""
    heads: dict[str, list[str]] = {}
    samples: dict[str, list[str]] = {}
    for body in bodies:
        current = ""
        for line in body.splitlines():
            if line.startswith("# HELP "):
                current = line[7:].split(" ", 1)[0]
                if current not in heads:
                    heads[current] = [line]
                    samples[current] = []
            elif line.startswith("# TYPE "):
                name = line[7:].split(" ", 1)[0]
                head = heads.setdefault(name, [])
                samples.setdefault(name, [])
                if not any(h.startswith("# TYPE ") for h in head):
                    head.append(line)
                current = name
            elif line.startswith("#") or not line.strip():
                continue
            else:
                samples.setdefault(current, []).append(line)
                heads.setdefault(current, [])
    out: list[str] = []
    for name, head in heads.items():
        if name in drop:
            continue
        out.extend(head)
        out.extend(samples[name])
    return "\n".join(out) + "\n" if out else ""


def _fetch(port: int, path: str) -> bytes:
    with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}",
                                timeout=FETCH_TIMEOUT_S) as resp:
        body: bytes = resp.read()
        return body


def _down_exposition(names: Sequence[str]) -> str:
    registry = CollectorRegistry()
    running = Gauge("compd_machine_running", "1 while the machine's daemon task runs, 0 "
                    "while it waits to be restarted", ["machine"], registry=registry)
    for name in names:
        running.labels(machine=name).set(0)
    return generate_latest(registry).decode()


class PoolMetrics(MetricsServer):
    """The parent's registry and its endpoint, answering for every worker."""

    def __init__(self, workers: Callable[[], list[WorkerView]]) -> None:
        self.registry = CollectorRegistry()
        self._workers = workers
        self.worker_running = Gauge("compd_worker_running",
                                    "1 while the worker process runs, 0 while it waits to "
                                    "be restarted", ["worker"], registry=self.registry)
        self.worker_restarts = Counter("compd_worker_restarts",
                                       "Times a worker process was restarted after it ended",
                                       ["worker"], registry=self.registry)
        self._pool = ThreadPoolExecutor(max_workers=4, thread_name_prefix="compd-scrape")
        self._init_server()

    def _gather(self, path: str) -> tuple[list[bytes], list[WorkerView]]:
        """Every worker's answer at `path`; the workers that gave none."""
        views = self._workers()
        asked = [(v, self._pool.submit(_fetch, v.port, path)) for v in views
                 if v.port is not None]
        answers: list[bytes] = []
        silent = [v for v in views if v.port is None]
        for view, future in asked:
            try:
                answers.append(future.result())
            except Exception:  # a worker restarting or too slow: its machines show down
                silent.append(view)
        return answers, silent

    def exposition(self) -> str:
        """The merged /metrics text."""
        answers, silent = self._gather("/metrics")
        own = generate_latest(self.registry).decode()
        down = [m for v in silent for m in v.machines]
        bodies = [a.decode("utf-8", "replace") for a in answers]
        merged = merge_expositions(bodies, drop=WORKER_PRIVATE)
        return merge_expositions([own, merged, _down_exposition(down) if down else ""])

    def status_document(self, refresh_s: float, history: bool) -> dict[str, Any]:
        """The workers' status documents as one, sorted by machine."""
        views = [v for v in self._workers() if v.paged]
        answers, silent = self._gather("/status.json")
        machines: list[dict[str, Any]] = []
        for answer in answers:
            machines.extend(json.loads(answer).get("machines", []))
        for view in silent:
            if view.paged:
                machines.extend({"machine": name, "state": "off", "healthy": False,
                                 "why": "its worker process is restarting", "age_s": None,
                                 "history": None} for name in view.paged)
        shown = {name for v in views for name in v.paged}
        machines = sorted((m for m in machines if m.get("machine") in shown),
                          key=lambda m: str(m.get("machine")))
        if not history or len(machines) > FLEET_HISTORY_MAX:
            for m in machines:
                m["history"] = None
        return {"machines": machines, "refresh_s": refresh_s}

    def app(self, refresh_s: float | None) -> WSGIApp:
        """The endpoint's WSGI app: /metrics merged; the status page when `refresh_s`
        is given (some file has [faces.http])."""

        def metrics(environ: dict[str, Any],
                    start_response: Callable[..., Any]) -> Iterable[bytes]:
            body = self.exposition().encode()
            headers = [("Content-Type", CONTENT_TYPE_LATEST)]
            if "gzip" in str(environ.get("HTTP_ACCEPT_ENCODING", "")):
                body = gzip.compress(body)
                headers.append(("Content-Encoding", "gzip"))
            headers.append(("Content-Length", str(len(body))))
            start_response("200 OK", headers)
            return [b"" if environ.get("REQUEST_METHOD") == "HEAD" else body]

        if refresh_s is None:
            return metrics
        every = refresh_s
        return with_status(lambda history: self.status_document(every, history),
                           lambda: every)(metrics)

    def serve(self, port: int, host: str, refresh_s: float | None,
              limits: HttpLimits | None) -> None:
        own = self.app(refresh_s)
        self.start_http(port, host, lambda _registry_app: own, limits)

    def stop(self) -> None:
        super().stop()
        self._pool.shutdown(wait=False, cancel_futures=True)
