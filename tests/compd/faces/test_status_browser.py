"""The operator page in a real headless browser (Debian's chromium through
chromedriver): it loads, shows the state and values of a running daemon against
a simulated controller, updates after a fault is injected, and says so when the
daemon no longer answers. A screenshot of
each is kept: under $COMPD_TEST_ARTIFACTS when set, else the test's tmp path
(the path is printed)."""

from __future__ import annotations

import asyncio
import os
from collections.abc import Callable, Coroutine
from pathlib import Path
from typing import Any

import pytest

from drivers.sim.modbus_server import ModbusSimController
from tests.compd.faces.status_helpers import page_daemon
from tests.compd.faces.webdriver import browser_missing, headless_chromium
from tests.harness import until

pytestmark = pytest.mark.skipif(browser_missing() is not None,
                                reason=str(browser_missing()))

_STATE = 'return document.querySelector("#m0 .state")?.textContent'
_CHANNELS = ('return [...document.querySelectorAll("#m0 table.channels tr")]'
             '.map(tr => [...tr.cells].map(td => td.textContent))')


def _artifacts(tmp_path: Path) -> Path:
    where = os.environ.get("COMPD_TEST_ARTIFACTS")
    out = Path(where) if where else tmp_path
    out.mkdir(parents=True, exist_ok=True)
    return out


def _browse(base: str, out: Path, loop: asyncio.AbstractEventLoop,
            inject: Callable[[], Coroutine[Any, Any, None]],
            stop: Callable[[], None]) -> dict[str, Any]:
    """In a thread: load the page, read it, inject the fault, read it again, stop
    the daemon and see the page say so."""
    seen: dict[str, Any] = {}  # what the page's scripts return: JSON values
    with headless_chromium() as browser:
        browser.get(base)
        browser.wait_for('return document.querySelector("#m0 .state")?.textContent === "on"')
        browser.wait_for('return Number(document.body.dataset.updates) >= 2')  # it refreshes
        seen["before"] = browser.script(_STATE), browser.script(_CHANNELS)
        seen["offset"] = browser.script('return document.querySelector("#m0 .offset")'
                                        '.textContent')
        seen["external"] = browser.script(
            'return performance.getEntriesByType("resource").map(e => e.name)'
            '.filter(u => !u.startsWith(location.origin))')
        seen["plotted"] = browser.script(
            'const c = document.querySelector("#m0 canvas.plot");'
            'const d = c.getContext("2d").getImageData(0, 0, c.width, c.height).data;'
            'let blue = 0; for (let i = 0; i < d.length; i += 4)'
            '  if (d[i] < 40 && d[i + 1] > 60 && d[i + 1] < 110 && d[i + 2] > 170) blue++;'
            'return blue;')
        seen["shot_on"] = browser.screenshot(out / "status-page-on.png")
        asyncio.run_coroutine_threadsafe(inject(), loop).result(10.0)
        browser.wait_for('return document.querySelector("#m0 .state")?.textContent '
                         '=== "holding"')
        browser.wait_for('return document.querySelector("#m0 table.alarms")'
                         '.textContent.includes("channel_invalid")')
        seen["after"] = browser.script(_STATE), browser.script(_CHANNELS)
        seen["why"] = browser.script('return document.querySelector("#m0 .why").textContent')
        seen["shot_fault"] = browser.screenshot(out / "status-page-holding.png")
        loop.call_soon_threadsafe(stop)
        seen["gone"] = browser.wait_for('return document.getElementById("stale")'
                                        '.textContent')
    seen["png"] = [Path(str(seen[k])).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
                   for k in ("shot_on", "shot_fault")]
    return seen


async def test_the_page_shows_the_daemon_and_follows_a_fault(
        sim: ModbusSimController, tmp_path: Path) -> None:
    await sim.publish({"bearing": 20.0, "ambient": 20.0})
    out = _artifacts(tmp_path)
    async with page_daemon(tmp_path, sim) as (daemon, base):
        await sim.publish({"bearing": 24.0, "ambient": 21.0})  # the offset moves
        await until(lambda: daemon.telemetry.complete_cycles >= 20)  # two recorder commits (of 10)

        async def bearing_out_of_range() -> None:
            await sim.publish({"bearing": 500.0, "ambient": 21.0})

        seen = await asyncio.to_thread(_browse, base, out, asyncio.get_running_loop(),
                                       bearing_out_of_range, daemon.request_stop)
    print(f"\nscreenshots: {seen['shot_on']} {seen['shot_fault']}")
    state, channels = seen["before"]
    assert state == "on"
    assert channels == [["bearing", "24.00 °C", "valid"], ["ambient", "21.00 °C", "valid"]]
    assert str(seen["offset"]).endswith(" \u00b5m")
    assert seen["external"] == []  # nothing fetched from anywhere but compd
    assert int(seen["plotted"]) > 50  # the offset line drawn
    state, channels = seen["after"]
    assert state == "holding" and "bearing: out_of_range" in str(seen["why"])
    assert channels[0] == ["bearing", "500.00 °C", "invalid: out_of_range"]
    assert str(seen["gone"]).startswith("no answer from compd")  # not old values as live
    assert seen["png"] == [True, True]
