"""A refused probe is logged once, then summarised, as write failures are (a probe
counter stepping every cycle with every probe refused writes no warning per cycle).
The metrics and the recorder still count every one."""

from __future__ import annotations

import asyncio
import contextlib
from pathlib import Path

import structlog

from compd.config.loader import load_config
from compd.runtime.daemon import Daemon
from compd.runtime.sdnotify import Notifier
from drivers.sim.modbus_server import ModbusSimController
from tests.configs import write_config
from tests.harness import until

ADAPTATION = """
[adaptation]
enabled = true
mode = "shadow"
probe_value = { kind = "input", address = 12, type = "float32" }
probe_counter = { kind = "input", address = 14, type = "uint16" }
"""


async def test_a_counter_stepping_every_cycle_logs_once_then_a_recovery(
        sim: ModbusSimController, tmp_path: Path) -> None:
    path = write_config(tmp_path, sim.endpoint)
    path.write_text(path.read_text() + ADAPTATION)
    cfg = load_config(path)
    await sim.publish({"probe_value": 500.0, "probe_counter": 1})  # far beyond the gate
    with structlog.testing.capture_logs() as logs:
        daemon = Daemon(cfg, notifier=Notifier(None))
        task = asyncio.create_task(daemon.run())

        async def step_the_counter() -> None:
            n = 1
            while True:
                n = n % 60000 + 1
                await sim.publish({"probe_counter": n})
                await asyncio.sleep(0.005)

        bumper = asyncio.create_task(step_the_counter())
        try:
            await until(lambda: daemon.running.cycle is not None
                        and daemon.running.cycle.probes is not None
                        and daemon.running.cycle.probes.adapter.refused >= 30)
            await sim.publish({"probe_value": 0.0})  # a good one (residual ≈ 0)
            await until(lambda: daemon.running.cycle is not None
                        and daemon.running.cycle.probes is not None
                        and daemon.running.cycle.probes.adapter.accepted >= 1)
        finally:
            bumper.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await bumper
        daemon.request_stop()
        assert await task == 0
    assert daemon.running.cycle is not None and daemon.running.cycle.probes is not None
    refused = daemon.running.cycle.probes.adapter.refused
    lines = [e for e in logs if e["event"].startswith("probe_refused")]
    # the first refusal in full; then (well within a minute) only the recovery's count
    assert lines[0]["event"] == "probe_refused" and lines[0]["reason"] == "gate"
    assert [e["event"] for e in lines].count("probe_refused") == 1
    assert not [e for e in lines if e["event"] == "probe_refused_summary"]
    (back,) = [e for e in lines if e["event"] == "probe_refused_recovered"]
    assert back["failures"] >= 30 and back["failures"] <= refused
    assert [e for e in logs if e["event"] == "probe_accepted"]
