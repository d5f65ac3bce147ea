"""`compd health --url` and `compd status --url` take the same URLs: the
daemon's base URL (``http://HOST:PORT/``, where its page, /status.json and
/metrics are served) and each its own path (and the other's), against a real
daemon serving them."""

from __future__ import annotations

import asyncio
import functools
from pathlib import Path

import pytest

from compd.cli import main
from compd.commands.health import metrics_url
from compd.commands.status import status_url
from drivers.sim.modbus_server import ModbusSimController
from tests.compd.faces.status_helpers import page_daemon
from tests.harness import healthy_within, until


def test_the_base_url_and_each_path_name_the_right_document() -> None:
    base = "http://127.0.0.1:9155"
    for url in (base, base + "/", base + "/status.json", base + "/metrics"):
        assert status_url(url) == base + "/status.json"
    for url in (base, base + "/", base + "/status.json", base + "/index.html"):
        assert metrics_url(url) == base + "/metrics"
    assert metrics_url(base + "/metrics") == base + "/metrics"
    assert metrics_url(base + "/custom/metrics") == base + "/custom/metrics"


async def test_health_and_status_both_take_the_daemon_base_url(
        sim: ModbusSimController, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    async with page_daemon(tmp_path, sim) as (daemon, base):
        await until(lambda: daemon.telemetry.complete_cycles >= 3)
        for url in (base, base.rstrip("/"), base + "metrics", base + "status.json"):
            capsys.readouterr()
            rc = await healthy_within(
                functools.partial(main, ["health", "--url", url, "--max-age-s", "600"]),
                lambda: daemon.telemetry.complete_cycles)
            out = capsys.readouterr().out.split("healthy: metrics: ")[-1]
            assert rc == 0, (url, out)
            assert "complete cycles" in out
            rc = await asyncio.to_thread(main, ["status", "--url", url])
            out = capsys.readouterr().out
            assert rc == 0, (url, out)
            assert "test" in out  # the machine's line
