"""A refused probe is logged once, then summarised, as write failures are (a probe
counter stepping every cycle with every probe refused writes no warning per cycle).
The metrics and the recorder still count every one."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import structlog

from compd.config.loader import load_config
from compd.runtime.driver_setup import build_driver
from compd.testing import RecordingDriver
from drivers.base import Driver, Sample
from drivers.sim.modbus_server import ModbusSimController
from tests.configs import write_config
from tests.harness import stepped_daemon

ADAPTATION = """
[adaptation]
enabled = true
mode = "shadow"
probe_value = { kind = "input", address = 12, type = "float32" }
probe_counter = { kind = "input", address = 14, type = "uint16" }
"""


class _CounterStepper(RecordingDriver):
    """The probe counter steps before every read: a new probe each cycle, however
    fast or slow the cycles run."""

    def __init__(self, inner: Driver, sim: ModbusSimController) -> None:
        super().__init__(inner)
        self.sim = sim
        self.counter = 1

    async def read(self, names: Sequence[str]) -> dict[str, Sample]:
        self.counter = self.counter % 60000 + 1
        await self.sim.publish({"probe_counter": self.counter})
        return await super().read(names)


async def test_a_counter_stepping_every_cycle_logs_once_then_a_recovery(
        sim: ModbusSimController, tmp_path: Path) -> None:
    """On a stepped clock with 0.4 s requests, the counter stepped by each read: 30
    refusals are 30 cycles (30 s on the daemon's clock, within the minute after which
    a summary would be due), whatever the machine's load."""
    path = write_config(tmp_path, sim.endpoint, time_scale=1.0)
    path.write_text(path.read_text() + ADAPTATION)
    cfg = load_config(path)
    await sim.publish({"probe_value": 500.0, "probe_counter": 1})  # far beyond the gate
    driver = _CounterStepper(build_driver(cfg), sim)
    with structlog.testing.capture_logs() as logs:
        async with stepped_daemon(cfg, driver=driver) as run:
            daemon = run.daemon
            await run.until(lambda: daemon.running.cycle is not None
                            and daemon.running.cycle.probes is not None
                            and daemon.running.cycle.probes.adapter.refused >= 30)
            await sim.publish({"probe_value": 0.0})  # a good one (residual ≈ 0)
            await run.until(lambda: daemon.running.cycle is not None
                            and daemon.running.cycle.probes is not None
                            and daemon.running.cycle.probes.adapter.accepted >= 1)
            assert await run.stop() == 0
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
