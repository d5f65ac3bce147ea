"""The one driver contract, run against every protocol.

Every ``tests/drivers/harness_<protocol>.py`` found next to this file is a
parameter (discovered, not listed: a new protocol joins by adding its
harness). Each harness starts its protocol's simulated controller on
127.0.0.1 and builds drivers for it (`tests.drivers.harness_types`).
"""

from __future__ import annotations

import asyncio
import contextlib
import importlib
import math
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest

from drivers.backoff import Backoff
from drivers.base import Driver, Quality, Sample
from drivers.errors import BadAddress, ConnectionLost, ControllerTimeout, DriverError
from drivers.sim import CHANNELS, OUTPUTS
from tests.drivers.harness_types import Harness

HARNESS_MODULES = sorted(
    p.stem for p in Path(__file__).parent.glob("harness_*.py") if p.stem != "harness_types")

#: channel values on a 0.1 grid (exact for 0.1-scaled integers), inside every
#: encoding's range; temperatures, rpm, kW, µm
KNOWN_VALUES: dict[str, float] = {
    "bearing": 31.2, "motor": 45.6, "column": 22.3, "table": -4.1, "ambient": 20.5,
    "spindle_rpm": 12000.0, "power_kw": 7.5, "growth_um": 12.25, "error_um": -3.5,
}
#: bound on any single call against a stopped server: "fast", not a hang
FAST_S = 5.0
#: bound on the reconnect loop after a restart
RECONNECT_WITHIN_S = 15.0


@pytest.fixture(params=HARNESS_MODULES, ids=lambda m: m.removeprefix("harness_"))
async def harness(request: pytest.FixtureRequest) -> AsyncIterator[Harness]:
    module: Any = importlib.import_module(f"tests.drivers.{request.param}")
    async with module.harness() as h:
        yield h


def _close_enough(got: float, want: float, tolerance: float) -> bool:
    return math.isfinite(got) and abs(got - want) <= tolerance + 1e-9 * abs(want)


async def _read_when_back(driver: Driver, names: list[str]) -> dict[str, Sample]:
    """Read until the driver has reconnected; tolerate the backoff's fast errors."""
    deadline = time.monotonic() + RECONNECT_WITHIN_S
    while True:
        try:
            return await asyncio.wait_for(driver.read(names), FAST_S)
        except (ConnectionLost, ControllerTimeout):
            if time.monotonic() > deadline:
                raise
            await asyncio.sleep(0.05)


def test_harnesses_found() -> None:
    assert "harness_modbus" in HARNESS_MODULES


async def test_harness_shape(harness: Harness) -> None:
    assert set(CHANNELS) <= set(harness.sim.channels)
    assert set(OUTPUTS) <= set(harness.sim.outputs_map)
    assert harness.sim.endpoint


async def test_read_all_channels(harness: Harness) -> None:
    await harness.sim.publish(KNOWN_VALUES)
    driver = harness.make_driver()
    try:
        await driver.connect()
        assert driver.connected
        before_s = time.time()
        samples = await driver.read(list(CHANNELS))
    finally:
        await driver.close()
    assert set(samples) == set(CHANNELS)
    for name, want in KNOWN_VALUES.items():
        sample = samples[name]
        assert isinstance(sample, Sample)
        assert _close_enough(sample.value, want, harness.tolerance), (name, sample, want)
        assert sample.quality is Quality.GOOD
        # a real timestamp (source or read time), not a placeholder
        assert sample.timestamp_s > before_s - 3600


async def test_read_connects_on_first_use(harness: Harness) -> None:
    await harness.sim.publish({"ambient": 19.5})
    driver = harness.make_driver()
    try:
        samples = await driver.read(["ambient"])
    finally:
        await driver.close()
    assert _close_enough(samples["ambient"].value, 19.5, harness.tolerance)


@pytest.mark.parametrize("offset_um", [12.5, -37.25, 0.0])
async def test_write_offset_and_read_back(harness: Harness, offset_um: float) -> None:
    driver = harness.make_driver()
    try:
        await driver.write({"offset": offset_um})
        via_driver = await driver.read(["offset"])
    finally:
        await driver.close()
    assert _close_enough(via_driver["offset"].value, offset_um, harness.tolerance)
    via_sim = await harness.sim.outputs()
    assert _close_enough(via_sim["offset"], offset_um, harness.tolerance)


async def test_write_heartbeat_and_status(harness: Harness) -> None:
    driver = harness.make_driver()
    try:
        await driver.write({"offset": 3.5, "heartbeat": 41, "status": 5})
        back = await driver.read(["heartbeat", "status", "offset"])
    finally:
        await driver.close()
    assert back["heartbeat"].value == pytest.approx(41)
    assert back["status"].value == pytest.approx(5)
    outputs = await harness.sim.outputs()
    assert outputs["heartbeat"] == pytest.approx(41)
    assert outputs["status"] == pytest.approx(5)


async def test_encodings_round_trip(harness: Harness) -> None:
    """k·scale for small k survives write/read; a negative value either
    survives or is refused with BadAddress (never wrapped around); at least
    one encoding holds negative numbers."""
    if not harness.encodings:
        pytest.skip("harness declares no extra encodings")
    driver = harness.make_driver(outputs={**harness.sim.outputs_map, **harness.encodings})
    negatives_held = 0
    try:
        for name, addr in harness.encodings.items():
            scale = float(getattr(addr, "scale", 1.0))
            for k in (0, 1, 123, -1, -123):
                want = k * scale
                try:
                    await driver.write({name: want})
                except BadAddress:
                    assert k < 0, f"{name} ({addr}) refused {want}"
                    continue
                got = (await driver.read([name]))[name].value
                assert _close_enough(got, want, harness.tolerance), (name, addr, want, got)
                negatives_held += k < 0
    finally:
        await driver.close()
    assert negatives_held > 0, "no encoding address held a negative number"


async def test_unknown_name_is_bad_address(harness: Harness) -> None:
    driver = harness.make_driver()
    try:
        with pytest.raises(BadAddress, match="no_such_channel"):
            await driver.read(["no_such_channel"])
        with pytest.raises(BadAddress, match="no_such_output"):
            await driver.write({"no_such_output": 1.0})
    finally:
        await driver.close()


async def test_bad_address_names_channel_and_address(harness: Harness) -> None:
    driver = harness.make_driver(channels={"bogus": harness.bad_address})
    try:
        with pytest.raises(BadAddress) as caught:
            await asyncio.wait_for(driver.read(["bogus"]), FAST_S)
    finally:
        await driver.close()
    message = str(caught.value)
    assert "bogus" in message
    assert harness.bad_address.describe() in message
    assert caught.value.channels == ("bogus",)


async def _connected(driver: Driver) -> None:
    """Connected to the running server: a busy machine may let a connect miss its
    0.5 s (seen in a run beside CPU hogs), so a few attempts (connect ignores the
    backoff); what the tests below judge is what follows."""
    for _ in range(9):
        with contextlib.suppress(ConnectionLost, ControllerTimeout):
            await driver.connect()
            return
    await driver.connect()


async def test_stopped_server_fails_fast(harness: Harness) -> None:
    driver = harness.make_driver(timeout_s=0.5)
    try:
        await _connected(driver)
        await driver.read(["ambient"])
        await harness.stop()
        for _ in range(3):  # the first call notices, the next ones fail fast too
            with pytest.raises((ConnectionLost, ControllerTimeout)):
                await asyncio.wait_for(driver.read(["ambient"]), FAST_S)
        with pytest.raises((ConnectionLost, ControllerTimeout)):
            await asyncio.wait_for(driver.write({"offset": 1.0}), FAST_S)
        assert not driver.connected
    finally:
        await driver.close()


async def test_never_started_server_fails_fast(harness: Harness) -> None:
    await harness.stop()
    driver = harness.make_driver(timeout_s=0.5)
    try:
        with pytest.raises((ConnectionLost, ControllerTimeout)):
            await asyncio.wait_for(driver.connect(), FAST_S)
        with pytest.raises((ConnectionLost, ControllerTimeout)):
            await asyncio.wait_for(driver.read(["ambient"]), FAST_S)
    finally:
        await driver.close()


async def test_same_driver_reconnects_after_restart(harness: Harness) -> None:
    await harness.sim.publish({"ambient": 21.5})
    driver = harness.make_driver(timeout_s=0.5)
    try:
        await driver.write({"offset": 7.5})
        await driver.read(["ambient"])
        await harness.restart()
        await harness.sim.publish({"ambient": 22.5})
        samples = await _read_when_back(driver, ["ambient"])
        assert _close_enough(samples["ambient"].value, 22.5, harness.tolerance)
        assert driver.connected
        # the restarted controller lost the offset; the same driver writes it again
        await driver.write({"offset": 7.5})
        assert _close_enough((await harness.sim.outputs())["offset"], 7.5, harness.tolerance)
    finally:
        await driver.close()


async def test_close_is_idempotent_and_leaves_no_tasks(harness: Harness) -> None:
    before = asyncio.all_tasks()
    driver = harness.make_driver()
    await driver.read(list(CHANNELS))
    await driver.close()
    await driver.close()
    assert not driver.connected
    for _ in range(20):
        leaked = asyncio.all_tasks() - before
        if not leaked:
            break
        await asyncio.sleep(0.01)
    assert not leaked, leaked
    never_used = harness.make_driver()
    await never_used.close()
    await never_used.close()


async def test_driver_error_types_are_driver_errors() -> None:
    for cls in (BadAddress, ConnectionLost, ControllerTimeout):
        assert issubclass(cls, DriverError)


def test_controller_timeout_is_also_a_timeout_error() -> None:
    assert issubclass(ControllerTimeout, TimeoutError)


# -- the link lifecycle (drivers.link): the same for every protocol --------------------

class FakeClock:
    """A monotonic clock the test moves: the backoff delay passes when told."""

    def __init__(self) -> None:
        self.now_s = 1000.0

    def __call__(self) -> float:
        return self.now_s


async def test_after_close_calls_fail_without_reconnecting(harness: Harness) -> None:
    """After close(): read and write raise ConnectionLost at once and do not
    reconnect (the controller is up); connect() opens the link again."""
    driver = harness.make_driver()
    try:
        await driver.read(["ambient"])
        await driver.close()
        for _ in range(2):
            with pytest.raises(ConnectionLost, match="closed"):
                await asyncio.wait_for(driver.read(["ambient"]), FAST_S)
            with pytest.raises(ConnectionLost, match="closed"):
                await asyncio.wait_for(driver.write({"offset": 1.0}), FAST_S)
        assert not driver.connected
        await driver.connect()
        assert driver.connected
        await harness.sim.publish({"ambient": 18.5})
        samples = await driver.read(["ambient"])
        assert _close_enough(samples["ambient"].value, 18.5, harness.tolerance)
    finally:
        await driver.close()
    assert not driver.connected


async def test_never_connected_driver_refuses_calls_after_close(harness: Harness) -> None:
    driver = harness.make_driver()
    await driver.close()
    with pytest.raises(ConnectionLost, match="closed"):
        await asyncio.wait_for(driver.read(["ambient"]), FAST_S)
    assert not driver.connected


async def test_backoff_gates_calls_until_the_delay_passed(harness: Harness) -> None:
    """A lost link starts the backoff delay: inside it every call fails fast
    with ConnectionLost without trying (a try on the stopped controller would
    count a failure); once the delay passed the next call tries again."""
    clock = FakeClock()
    backoff = Backoff(initial_s=1.0, cap_s=4.0, clock=clock)
    driver = harness.make_driver(backoff=backoff)
    try:
        await driver.read(["ambient"])
        await harness.stop()
        with pytest.raises((ConnectionLost, ControllerTimeout)):
            await asyncio.wait_for(driver.read(["ambient"]), FAST_S)
        assert not driver.connected
        assert backoff.failures == 1
        for _ in range(2):
            with pytest.raises(ConnectionLost, match="backing off"):
                await asyncio.wait_for(driver.read(["ambient"]), FAST_S)
            with pytest.raises(ConnectionLost, match="backing off"):
                await asyncio.wait_for(driver.write({"offset": 2.5}), FAST_S)
        assert backoff.failures == 1, "a call inside the backoff delay tried to connect"
        clock.now_s += backoff.delay_s
        with pytest.raises((ConnectionLost, ControllerTimeout)):
            await asyncio.wait_for(driver.read(["ambient"]), FAST_S)
        assert backoff.failures == 2, "the call after the delay did not try to reconnect"
        assert backoff.delay_s == 2.0
        with pytest.raises(ConnectionLost, match="backing off"):
            await asyncio.wait_for(driver.read(["ambient"]), FAST_S)
    finally:
        await driver.close()


async def test_failed_connect_starts_the_backoff(harness: Harness) -> None:
    """connect() tries whatever the backoff says; its failure is a driver
    error and starts the delay, so the next read or write fails fast."""
    clock = FakeClock()
    backoff = Backoff(initial_s=1.0, cap_s=4.0, clock=clock)
    await harness.stop()
    driver = harness.make_driver(backoff=backoff)
    try:
        for expected_failures in (1, 2):  # the second inside the delay: tried all the same
            with pytest.raises((ConnectionLost, ControllerTimeout)):
                await asyncio.wait_for(driver.connect(), FAST_S)
            assert backoff.failures == expected_failures
        with pytest.raises(ConnectionLost, match="backing off"):
            await asyncio.wait_for(driver.read(["ambient"]), FAST_S)
        with pytest.raises(ConnectionLost, match="backing off"):
            await asyncio.wait_for(driver.write({"offset": 1.0}), FAST_S)
        assert backoff.failures == 2
        assert not driver.connected
    finally:
        await driver.close()


async def _read_until_back(driver: Driver, clock: FakeClock) -> dict[str, Sample]:
    """Read until the driver has reconnected, moving the fake clock past each
    backoff delay (a stalled worker may time out a reconnect attempt or two)."""
    deadline = time.monotonic() + RECONNECT_WITHIN_S
    while True:
        try:
            return await asyncio.wait_for(driver.read(["ambient"]), FAST_S)
        except (ConnectionLost, ControllerTimeout):
            if time.monotonic() > deadline:
                raise
            clock.now_s += 60.0
            await asyncio.sleep(0.05)


async def test_after_a_timeout_the_link_is_dropped_then_reopened(harness: Harness) -> None:
    """A call the controller does not answer raises ControllerTimeout (a
    TimeoutError too) within its timeout; the link is dropped (a late answer
    must not be taken for the next request's) and backs off; once the
    controller answers again the same driver reconnects."""
    clock = FakeClock()
    backoff = Backoff(initial_s=1.0, cap_s=4.0, clock=clock)
    driver = harness.make_stallable_driver(timeout_s=0.3, backoff=backoff)
    try:
        await asyncio.wait_for(driver.read(["ambient"]), FAST_S)
        harness.stall()
        with pytest.raises(ControllerTimeout) as caught:
            await asyncio.wait_for(driver.read(["ambient"]), FAST_S)
        assert isinstance(caught.value, TimeoutError)
        assert not driver.connected
        assert backoff.failures == 1
        with pytest.raises(ConnectionLost, match="backing off"):
            await asyncio.wait_for(driver.write({"offset": 4.5}), FAST_S)
        harness.unstall()
        await harness.sim.publish({"ambient": 24.5})
        samples = await _read_until_back(driver, clock)
        assert _close_enough(samples["ambient"].value, 24.5, harness.tolerance)
        assert driver.connected and backoff.failures == 0
        await asyncio.wait_for(driver.write({"offset": 4.5}), FAST_S)
    finally:
        harness.unstall()
        await driver.close()
    assert await harness.idle(), "the stalled connection outlived close()"
