"""A daemon with the operator page ([faces.http]) against a simulated controller,
for the status page's HTTP and browser tests."""

from __future__ import annotations

import asyncio
import contextlib
import urllib.error
import urllib.request
from collections.abc import AsyncIterator
from pathlib import Path

from compd.config.loader import load_config
from compd.runtime.daemon import Daemon
from compd.runtime.sdnotify import Notifier
from drivers.sim.modbus_server import ModbusSimController
from drivers.sim.ports import free_tcp_port
from tests.compd.daemon_helpers import until, write_config

FACES_HTTP = "\n[faces.http]\nenabled = true\nrefresh_s = {refresh_s}\n"


@contextlib.asynccontextmanager
async def page_daemon(tmp_path: Path, sim: ModbusSimController, *, time_scale: float = 10.0,
                      refresh_s: float = 1.0,
                      recorder: bool = True) -> AsyncIterator[tuple[Daemon, str]]:
    """A running daemon serving the page; yields it and its base URL (``http://.../``)."""
    path = write_config(tmp_path, sim.endpoint, time_scale=time_scale)
    if not recorder:
        path.write_text(path.read_text().replace("[recorder]\n", "[recorder]\nenabled = false\n"))
    port = free_tcp_port("127.0.0.1")
    path.write_text(path.read_text() + f"metrics_port = {port}\n"
                    + FACES_HTTP.format(refresh_s=refresh_s), encoding="utf-8")
    daemon = Daemon(load_config(path), notifier=Notifier(None))
    task = asyncio.create_task(daemon.run())
    try:
        await until(lambda: daemon.complete_cycles >= 3 or task.done())
        assert not task.done(), "the daemon ended early"
        yield daemon, f"http://127.0.0.1:{port}/"
    finally:
        daemon.request_stop()
        assert await asyncio.wait_for(task, 20.0) == 0


def get(url: str, method: str = "GET", timeout_s: float = 5.0) -> tuple[int, str, bytes]:
    """(status, content type, body) of one request; HTTP errors are answers too."""
    req = urllib.request.Request(url, method=method)
    try:
        with urllib.request.urlopen(req, timeout=timeout_s) as resp:
            return resp.status, resp.headers.get("Content-Type", ""), resp.read()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.headers.get("Content-Type", ""), exc.read()
