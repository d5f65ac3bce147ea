"""``/`` and ``/status.json`` beside ``/metrics`` (``[faces.http]``).

`with_status(document, refresh_s)` wraps the Prometheus WSGI app: ``/``
answers the operator page (`compd.faces.status_page`, the last snapshot
inlined so that it shows at once), ``/status.json`` the snapshot plus the
recorder's history, ``/metrics`` the metrics as before; any other path is
404 (the page's server is not a catch-all). Read-only: any method but GET
and HEAD is refused with 405; the query string is ignored. A failure here
answers 500 to that one request; the cycle never waits on it (a snapshot is
a dict the loop replaces, never one it mutates).

`daemon_document(board)` is one machine's document; `fleet_document(boards)`
the document of a process serving several (`compd run DIR`): ``machines``, a
list of the machines' documents (the plot's history only for a few machines).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Iterable, Mapping
from typing import Any

from compd.faces.status import StatusBoard
from compd.faces.status_page import render_page
from compd.faces.telemetry import WSGIApp

__all__ = ["FLEET_HISTORY_MAX", "daemon_document", "fleet_document", "with_status"]

#: a fleet's document carries the plot's history only up to this many machines
FLEET_HISTORY_MAX = 16

_PAGE_PATHS = frozenset({"/", "/index.html"})


def _finite(value: Any) -> Any:
    """JSON has no NaN or Infinity: they become null."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    return value


def daemon_document(board: StatusBoard, *, history: bool = True) -> dict[str, Any]:
    """One machine: the last snapshot, its age (``age_s``, real seconds since the
    loop published it: a stalled loop shows), the refresh period and the recorder's
    history."""
    doc = dict(board.snapshot)
    wall_s = doc.get("wall_s")
    doc["age_s"] = max(0.0, time.time() - wall_s) if isinstance(wall_s, float) else None
    doc["refresh_s"] = board.refresh_s
    doc["history"] = board.history() if history else None
    finite: dict[str, Any] = _finite(doc)  # a dict in, a dict out
    return finite


def fleet_document(boards: Mapping[str, StatusBoard], refresh_s: float,
                   *, history: bool = True) -> dict[str, Any]:
    """Several machines (sorted by name), each its own document."""
    with_history = history and len(boards) <= FLEET_HISTORY_MAX
    machines = []
    for name, board in sorted(boards.items()):
        doc = daemon_document(board, history=with_history)
        doc.setdefault("machine", name)
        machines.append(doc)
    return {"machines": machines, "refresh_s": refresh_s}


def _answer(start_response: Callable[..., Any], status: str, body: bytes, ctype: str,
            head: bool, extra: list[tuple[str, str]] | None = None) -> list[bytes]:
    start_response(status, [("Content-Type", ctype), ("Content-Length", str(len(body))),
                            ("Cache-Control", "no-store"), *(extra or [])])
    return [b"" if head else body]


def with_status(document: Callable[[bool], dict[str, Any]],
                refresh_s: Callable[[], float]) -> Callable[[WSGIApp], WSGIApp]:
    """A wrapper of the metrics app that adds the page's two paths. `document(history)`:
    what /status.json answers (the page inlines it without history)."""

    def wrap(metrics_app: WSGIApp) -> WSGIApp:
        def app(environ: dict[str, Any], start_response: Callable[..., Any]) -> Iterable[bytes]:
            path = str(environ.get("PATH_INFO", "/"))
            method = str(environ.get("REQUEST_METHOD", "GET"))
            head = method == "HEAD"
            if method not in ("GET", "HEAD"):
                return _answer(start_response, "405 Method Not Allowed", b"read-only\n",
                               "text/plain; charset=utf-8", False, [("Allow", "GET, HEAD")])
            if path == "/metrics":
                return metrics_app(environ, start_response)
            if path not in _PAGE_PATHS and path != "/status.json":
                return _answer(start_response, "404 Not Found",
                               b"not found: / (the page), /status.json, /metrics\n",
                               "text/plain; charset=utf-8", head)
            try:
                if path == "/status.json":
                    body = json.dumps(document(True)).encode()
                    ctype = "application/json"
                else:
                    body = render_page(document(False), refresh_s()).encode()
                    ctype = "text/html; charset=utf-8"
            except Exception as exc:  # this one request fails, nothing else
                return _answer(start_response, "500 Internal Server Error",
                               f"status unavailable: {type(exc).__name__}\n".encode(),
                               "text/plain; charset=utf-8", head)
            return _answer(start_response, "200 OK", body, ctype, head)

        return app

    return wrap
