"""Each Modbus request's deadline on one timer per link (`drivers.modbus_watch`):
a request still ends at its own deadline, a cycle's requests arm one timer, and
pymodbus's own per-request timer is taken away only where the watch can end a
request instead. The event loop's time is a `FakeClock` here (moved by the test)."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from types import SimpleNamespace
from typing import Any

import pytest

from compd.testing import FakeClock
from drivers.errors import ControllerTimeout
from drivers.modbus_watch import RequestWatch, response_future, untimed
from drivers.sim.modbus_server import ModbusSimController
from tests.drivers.test_modbus import driver_for


@pytest.fixture
async def clock() -> AsyncIterator[FakeClock]:
    """The running loop's time, moved only by the test."""
    loop = asyncio.get_running_loop()
    fake = FakeClock(start_s=100.0)
    loop.time = fake  # type: ignore[method-assign]
    try:
        yield fake
    finally:
        del loop.time


def _client() -> Any:
    """What the watch uses of a pymodbus client: its response future and params."""
    future = asyncio.get_running_loop().create_future()
    return SimpleNamespace(ctx=SimpleNamespace(
        response_future=future, comm_params=SimpleNamespace(timeout_connect=0.5)))


async def _settle() -> None:
    for _ in range(3):
        await asyncio.sleep(0)


async def test_a_request_ends_at_its_own_deadline(clock: FakeClock) -> None:
    """A request that begins after the timer was armed (by an earlier request) is
    failed at its own start + timeout_s: not at the timer's first firing, not later."""
    watch = RequestWatch(0.5)
    first, second = _client(), _client()
    watch.begin(first)
    watch.end()  # answered at once
    clock.advance(0.3)
    watch.begin(second)  # in flight from 100.3: its deadline is 100.8
    clock.advance(0.2)  # 100.5: the timer armed by the first request fires
    await _settle()
    assert not second.ctx.response_future.done()
    clock.advance(0.29)  # 100.79
    await _settle()
    assert not second.ctx.response_future.done()
    clock.advance(0.01)  # 100.8
    await _settle()
    assert isinstance(second.ctx.response_future.exception(), TimeoutError)
    assert not first.ctx.response_future.done()
    assert watch.armed == 2


async def test_a_cycle_of_requests_arms_one_timer(clock: FakeClock) -> None:
    watch = RequestWatch(0.5)
    client = _client()
    for _ in range(3):  # a cycle: input block, read-back, write
        watch.begin(client)
        clock.advance(0.001)
        watch.end()
    assert watch.armed == 1
    clock.advance(0.5)  # the timer fires with nothing in flight: nothing failed
    await _settle()
    assert not client.ctx.response_future.done()
    assert watch.armed == 1  # and it is not armed again until the next request
    clock.advance(0.5)
    watch.begin(client)
    assert watch.armed == 2
    watch.close()
    clock.advance(1.0)
    await _settle()
    assert not client.ctx.response_future.done()  # closed: the timer was cancelled


async def test_an_answered_request_is_not_failed(clock: FakeClock) -> None:
    watch = RequestWatch(0.5)
    client = _client()
    watch.begin(client)
    client.ctx.response_future.set_result("answer")  # arrived; the task not resumed yet
    clock.advance(0.6)
    await _settle()
    assert client.ctx.response_future.result() == "answer"
    watch.close()


def test_pymodbus_keeps_its_timeout_where_the_watch_cannot_end_a_request() -> None:
    """A pymodbus without the response future the watch sets: its own timer stays."""
    client: Any = SimpleNamespace(ctx=SimpleNamespace(
        comm_params=SimpleNamespace(timeout_connect=0.5)))
    assert response_future(client) is None
    assert untimed(client) is False
    assert client.ctx.comm_params.timeout_connect == 0.5


async def test_the_driver_times_each_request_with_its_watch() -> None:
    """On a real link: pymodbus's own per-request timeout is off once connected, the
    reads of a cycle arm one timer, and a hung controller still times out."""
    sim = ModbusSimController()
    await sim.start()
    driver = driver_for(sim, timeout_s=0.2)
    try:
        await driver.connect()
        client = driver._link.session
        assert client is not None
        assert client.ctx.comm_params.timeout_connect is None
        armed = driver._watch.armed
        await driver.read(["bearing", "offset"])  # two requests
        await driver.write({"offset": 1.0})  # a third
        assert driver._watch.armed == armed + 1
        sim.set_hang(True)
        with pytest.raises(ControllerTimeout):
            await asyncio.wait_for(driver.read(["bearing"]), 5.0)
    finally:
        sim.set_hang(False)
        await driver.close()
        await sim.stop()
