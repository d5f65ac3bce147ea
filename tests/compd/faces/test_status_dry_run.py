"""A dry run is its own state on the status page, in /status.json and in
`compd status`: "dry-run", not the green "on" (nothing it computes reaches
the machine), and its plot says why it stays empty."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import pytest

from compd.cli import main
from compd.config.loader import load_config
from compd.core.faults import FaultState
from compd.core.health import Cause
from compd.faces.status import operator_state
from compd.faces.status_page import render_page
from compd.runtime.daemon import Daemon
from compd.runtime.sdnotify import Notifier
from drivers.sim.modbus_server import ModbusSimController
from drivers.sim.ports import free_tcp_port
from tests.compd.faces.status_helpers import FACES_HTTP, get
from tests.configs import write_config
from tests.harness import until


def test_a_dry_run_that_would_compensate_is_not_on() -> None:
    word, why = operator_state(FaultState.OK, Cause.IN_FORCE, {"bearing": None}, dry_run=True)
    assert word == "dry-run"
    assert "nothing is written" in why
    # a fault in a dry run keeps its own word, and says it is a dry run
    word, why = operator_state(FaultState.HOLD, Cause.INPUTS_INVALID, {"bearing": "stale"},
                               dry_run=True)
    assert word == "holding" and why.endswith("dry run: nothing is written")
    assert operator_state(FaultState.OK, Cause.IN_FORCE, {"bearing": None})[0] == "on"


def test_the_page_styles_the_dry_run_state_apart_from_on() -> None:
    page = render_page({"machine": "m", "state": "dry-run", "channels": []}, 5.0)
    assert ".state.dry-run{" in page


async def test_a_dry_run_daemon_says_dry_run_everywhere(
        sim: ModbusSimController, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = write_config(tmp_path, sim.endpoint, time_scale=10.0)
    port = free_tcp_port("127.0.0.1")
    path.write_text(path.read_text() + f"metrics_port = {port}\n"
                    + FACES_HTTP.format(refresh_s=1.0), encoding="utf-8")
    daemon = Daemon(load_config(path), dry_run=True, notifier=Notifier(None))
    task = asyncio.create_task(daemon.run())
    base = f"http://127.0.0.1:{port}/"
    try:
        await until(lambda: daemon.status_board.snapshot.get("sequence", 0) >= 3
                    or task.done())
        assert not task.done()
        code, _, body = await asyncio.to_thread(get, base + "status.json")
        doc = json.loads(body)
        assert code == 200
        assert doc["state"] == "dry-run" and doc["dry_run"] is True
        assert doc["why"].startswith("dry run:")
        assert doc["history"]["wall_s"] == []
        assert doc["history"]["error"].startswith("dry run: nothing is recorded")
        code, _, page = await asyncio.to_thread(get, base)
        assert code == 200 and b'"state": "dry-run"' in page
        capsys.readouterr()
        rc = await asyncio.to_thread(main, ["status", "--url", base])
        lines = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("test:")]
        assert rc == 1  # not compensating
        assert lines and lines[0].startswith("test: dry-run - dry run:")
    finally:
        daemon.request_stop()
        assert await asyncio.wait_for(task, 20.0) == 0
