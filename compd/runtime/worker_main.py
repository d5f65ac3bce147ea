"""One worker process of `compd run DIR --workers N` (`compd.runtime.workers`).

The parent starts it as ``python -m compd.runtime.worker_main`` and writes its
spec as one JSON line on stdin: ``index``, ``files`` (its share of the
directory's machine configs), ``dry_run``, ``serve`` (whether the directory
asks for a metrics endpoint) and ``log`` (the first file's logging settings,
so that every process of the directory logs alike). The worker then is what
`compd run DIR` is in one process (`compd.runtime.fleet.Fleet`) for its own
machines: each machine a supervised task, restarted alone after a crash;
SIGHUP reloads each machine's own file; SIGTERM stops each with its shutdown
policy and checkpoint, and the worker exits 0. A file that no longer validates
exits 78 naming it (the parent validated every file before starting any
worker: this is a file edited since).

It talks to its parent only through what a service talks to systemd through:

- sd_notify on ``$NOTIFY_SOCKET`` (the parent's socket for this worker):
  ``READY=1`` with ``MAINPID`` and ``COMPD_METRICS_PORT``, the loopback port
  (chosen free) on which its machines' /metrics and /status.json answer;
  ``WATCHDOG=1`` while its event loop runs (every half ``$WATCHDOG_USEC``);
  ``STATUS=`` "N machines, M compensating";
- its stdin stays open: its end (the parent gone, even by SIGKILL) stops the
  worker as SIGTERM would, so that no orphan keeps the machines' state locks.

Its log lines carry ``worker`` (the index) beside ``machine``.
"""

from __future__ import annotations

import asyncio
import json
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import structlog

from compd.config.loader import LoadedConfig, load_config
from compd.errors import ConfigError
from compd.runtime.sdnotify import Notifier
from compd.sysexits import EX_CONFIG, EX_USAGE

__all__ = ["WorkerNotifier", "main"]


class WorkerNotifier(Notifier):
    """sd_notify to the parent; READY=1 also names the loopback metrics port."""

    def __init__(self, port: Callable[[], int | None]) -> None:
        super().__init__()
        self._port = port

    def ready(self) -> None:
        port = self._port()
        extra = f"\nCOMPD_METRICS_PORT={port}" if port is not None else ""
        self.notify(f"READY=1\nMAINPID={os.getpid()}{extra}")


def _load(files: list[str]) -> list[LoadedConfig]:
    """Every file, validated; ConfigError naming each bad one (as `load_machines`)."""
    loaded: list[LoadedConfig] = []
    bad: list[str] = []
    for name in files:
        try:
            loaded.append(load_config(Path(name)))
        except ConfigError as exc:
            bad.append(f"{name}: {exc}")
    if bad:
        raise ConfigError("", "; ".join(bad))
    return loaded


def _stop_when_parent_goes(loop: asyncio.AbstractEventLoop, stop: Callable[[], None]) -> None:
    """The end of stdin (the parent's end of the pipe closed): stop."""
    fd = sys.stdin.fileno()

    def readable() -> None:
        try:
            data = os.read(fd, 4096)
        except BlockingIOError:
            return
        except OSError:
            data = b""
        if not data:
            loop.remove_reader(fd)
            structlog.get_logger("compd").warning("parent_gone", action="stop")
            stop()

    loop.add_reader(fd, readable)


async def _serve(spec: dict[str, Any], configs: list[LoadedConfig]) -> int:
    from compd.runtime.fleet import Fleet, build_drivers

    fleet: Fleet | None = None

    def port() -> int | None:
        return None if fleet is None else fleet.metrics.port

    fleet = Fleet(configs, dry_run=bool(spec.get("dry_run")), drivers=build_drivers(configs),
                  notifier=WorkerNotifier(port))
    # the parent serves the directory's endpoint; this worker answers it on loopback
    fleet.endpoint = ("127.0.0.1", 0) if spec.get("serve") else None
    loop = asyncio.get_running_loop()
    _stop_when_parent_goes(loop, fleet.request_stop)
    try:
        return await fleet.run()
    finally:
        loop.remove_reader(sys.stdin.fileno())


def main() -> int:
    line = sys.stdin.buffer.readline()
    try:
        spec = json.loads(line)
        index = int(spec["index"])
        files = [str(f) for f in spec["files"]]
        log = dict(spec.get("log") or {})
    except (ValueError, KeyError, TypeError):
        print("compd worker: no spec on stdin (started by compd run DIR --workers N)",
              file=sys.stderr)
        return EX_USAGE
    from compd.faces.telemetry import configure_logging

    configure_logging(json=log.get("json"), level=str(log.get("level", "info")),
                      library_level=str(log.get("library_level", "default")))
    structlog.contextvars.bind_contextvars(worker=index)
    try:
        configs = _load(files)
    except ConfigError as exc:
        print(f"compd worker {index}: configuration error: {exc}", file=sys.stderr)
        return EX_CONFIG
    return asyncio.run(_serve(spec, configs))


if __name__ == "__main__":
    sys.exit(main())
