"""The shipped test doubles (`compd.testing`) behave as the daemon needs them:
the in-memory driver keeps the `Driver` rules, and the real daemon shell runs
whole cycles against it without a socket."""

from __future__ import annotations

from pathlib import Path

import pytest

from compd.config.loader import load_config
from compd.core.output import Status
from compd.runtime.daemon import Daemon
from compd.runtime.sdnotify import Notifier
from compd.testing import FakeClock, MemoryDriver, RecordingDriver
from drivers.base import Driver, Quality
from drivers.errors import BadAddress, ConnectionLost, ControllerTimeout
from tests.configs import write_config

OUTPUTS = ("offset", "heartbeat", "status")


def _driver() -> MemoryDriver:
    return MemoryDriver({"bearing": 20.0, "ambient": 20.0}, OUTPUTS)


def test_fake_clock_moves_only_when_told() -> None:
    clock = FakeClock(period_s=0.5, start_s=100.0)
    assert clock() == 100.0 and clock() == 100.0
    assert clock.tick() == 100.5 and clock() == 100.5
    assert clock.advance(3600.0) == 3700.5


async def test_memory_driver_keeps_the_driver_rules() -> None:
    driver = _driver()
    assert isinstance(driver, Driver)
    with pytest.raises(ConnectionLost):
        await driver.read(["bearing"])  # not connected yet
    await driver.connect()
    driver.set("bearing", 31.5, Quality.BAD)
    got = await driver.read(["bearing", "offset"])
    assert (got["bearing"].value, got["bearing"].quality) == (31.5, Quality.BAD)
    assert got["offset"].value == 0.0
    with pytest.raises(BadAddress, match="spindle"):
        await driver.read(["spindle"])
    with pytest.raises(BadAddress, match="bearing"):
        await driver.write({"bearing": 1.0})  # a channel is not an output
    await driver.write({"offset": 12.5})
    assert driver.outputs["offset"] == 12.5 and driver.writes == [{"offset": 12.5}]
    driver.fail_next_write = ControllerTimeout("injected")
    with pytest.raises(ControllerTimeout):
        await driver.write({"offset": 13.0})
    await driver.write({"offset": 13.0})  # the injected failure was for one write only
    assert driver.outputs["offset"] == 13.0
    await driver.close()
    with pytest.raises(ConnectionLost):
        await driver.write({"offset": 14.0})


async def test_the_daemon_runs_a_cycle_against_memory(tmp_path: Path) -> None:
    cfg = load_config(write_config(tmp_path, "modbus://127.0.0.1:1"))
    memory = _driver()
    driver = RecordingDriver(memory)
    daemon = Daemon(cfg, driver=driver, once=True, notifier=Notifier(None))
    assert await daemon.run() == 0
    assert daemon.loop.last_result is not None and daemon.loop.last_result.inputs_valid
    assert memory.outputs["heartbeat"] == 1.0
    assert int(memory.outputs["status"]) & Status.OK
    # read back (0.0 from a fresh controller), then written
    assert driver.cycles == [(0.0, memory.outputs["offset"])]
    assert not memory.connected  # the daemon closed it


async def test_an_injected_read_failure_holds_the_cycle(tmp_path: Path) -> None:
    cfg = load_config(write_config(tmp_path, "modbus://127.0.0.1:1"))
    memory = _driver()
    memory.fail_next_read = ConnectionLost("injected")
    daemon = Daemon(cfg, driver=memory, once=True, notifier=Notifier(None))
    assert await daemon.run() == 1  # the one cycle was not complete
    assert daemon.loop.last_result is not None and not daemon.loop.last_result.inputs_valid
    assert memory.reads == 1 and memory.fail_next_read is None
    # no offset written without a read-back, and the heartbeat did not advance
    assert all("offset" not in w for w in memory.writes)
    assert memory.outputs["heartbeat"] == 0.0
