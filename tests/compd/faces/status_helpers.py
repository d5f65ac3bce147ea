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
from compd.testing import SteppedClock
from drivers.sim.modbus_server import ModbusSimController
from drivers.sim.ports import free_tcp_port
from tests.configs import write_config
from tests.harness import asleep, until

FACES_HTTP = "\n[faces.http]\nenabled = true\nrefresh_s = {refresh_s}\n"


@contextlib.asynccontextmanager
async def page_daemon(tmp_path: Path, sim: ModbusSimController, *, time_scale: float = 10.0,
                      refresh_s: float = 1.0, recorder: bool = True,
                      stepped: bool = False) -> AsyncIterator[tuple[Daemon, str]]:
    """A running daemon serving the page; yields it and its base URL (``http://.../``).

    `stepped`: the daemon in lockstep on a `compd.testing.SteppedClock`
    (``daemon.clock``; `step` runs its cycles) at time_scale 1 with a 0.5 s
    request timeout: it cycles only when the test says, and a loaded machine's
    late answer is never a failed read."""
    clock: SteppedClock | None = None
    if stepped:
        time_scale, clock = 1.0, SteppedClock(period_s=1.0)
    port = free_tcp_port("127.0.0.1")
    path = write_config(tmp_path, sim.endpoint, time_scale=time_scale,
                        timeout_s=0.5 if stepped else None,
                        swap=() if recorder else [("[recorder]\n",
                                                   "[recorder]\nenabled = false\n")],
                        extra=f"metrics_port = {port}\n" + FACES_HTTP.format(refresh_s=refresh_s))
    if clock is None:
        daemon = Daemon(load_config(path), notifier=Notifier(None))
    else:
        daemon = Daemon(load_config(path), notifier=Notifier(None), clock=clock,
                        sleep=clock.sleep)
    task = asyncio.create_task(daemon.run())
    try:
        if clock is None:
            await until(lambda: daemon.telemetry.complete_cycles >= 3 or task.done())
        else:
            await asleep(clock, 1, task)
            await step(daemon, 2)
        assert not task.done(), "the daemon ended early"
        yield daemon, f"http://127.0.0.1:{port}/"
    finally:
        daemon.request_stop()
        assert await asyncio.wait_for(task, 120.0) == 0


async def step(daemon: Daemon, periods: int = 1) -> None:
    """`periods` cycles of a `page_daemon(stepped=True)` daemon, each run to its end."""
    clock = daemon.clock.mono
    assert isinstance(clock, SteppedClock), "page_daemon(stepped=True) only"
    for _ in range(periods):
        n = clock.sleeps + 1
        clock.tick()
        await clock.cycle_done(n)


def get(url: str, method: str = "GET", timeout_s: float = 5.0) -> tuple[int, str, bytes]:
    """(status, content type, body) of one request; HTTP errors are answers too."""
    req = urllib.request.Request(url, method=method)
    try:
        with urllib.request.urlopen(req, timeout=timeout_s) as resp:
            return resp.status, resp.headers.get("Content-Type", ""), resp.read()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.headers.get("Content-Type", ""), exc.read()
