"""The log always says which controller the daemon talks to: a connect that
fails (a slow controller, a busy PC) is followed, when the link comes up, by
``controller_connected`` naming the endpoint, once."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

from compd.config.loader import load_config
from drivers.errors import ConnectionLost
from tests.configs import write_config
from tests.harness import EventLog, memory_daemon

ENDPOINT = "127.0.0.1:1"


def _named(log: EventLog, event: str) -> list[tuple[str, dict[str, Any]]]:
    return [(level, fields) for level, name, fields in log.events if name == event]


async def _run(tmp_path: Path, *, connect_fails: bool) -> EventLog:
    cfg = load_config(write_config(tmp_path, ENDPOINT, time_scale=1.0, timeout_s=0.4))
    log = EventLog()
    daemon, clock, driver = memory_daemon(cfg, log=log)
    if connect_fails:
        driver.fail_next_connect = ConnectionLost("connect timed out")
    task = asyncio.create_task(daemon.run())
    try:
        await clock.cycle_done(1)
        if connect_fails:  # the reads fail until the driver's own retry gets through
            assert not driver.connected and not _named(log, "controller_connected")
            await driver.connect()
        for n in range(2, 6):
            clock.tick()
            await clock.cycle_done(n)
    finally:
        daemon.request_stop()
        assert await task == 0
    return log


async def test_a_failed_connect_is_announced_with_its_endpoint_when_the_link_comes_up(
        tmp_path: Path) -> None:
    log = await _run(tmp_path, connect_fails=True)
    assert _named(log, "controller_connect_failed") == [
        ("warning", {"endpoint": ENDPOINT, "error": "connect timed out"})]
    assert _named(log, "controller_connected") == [
        ("info", {"endpoint": ENDPOINT, "after": "connect_failed"})]
    assert not _named(log, "controller_reconnected")  # one line for the link coming up


async def test_a_connect_that_succeeds_is_announced_once(tmp_path: Path) -> None:
    log = await _run(tmp_path, connect_fails=False)
    assert _named(log, "controller_connected") == [("info", {"endpoint": ENDPOINT})]
    assert not _named(log, "controller_connect_failed")
