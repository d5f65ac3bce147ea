"""A simulated controller whose picked port is taken before it binds starts on
another; a port its caller named is never changed.

The race this covers: a port found free is handed back to the kernel's
ephemeral range until the server binds it, and any outgoing connection on the
machine may take it as its source port meanwhile (seen as EADDRINUSE in a
suite run on a loaded machine). Here the port is taken on purpose between the
pick and the start.
"""

from __future__ import annotations

import asyncio
import logging
import socket
from collections.abc import Iterator
from contextlib import contextmanager
from urllib.parse import urlsplit

import pytest

from drivers.factory import open_driver
from drivers.sim.registry import make_sim_controller

PROTOCOLS = ["opcua", "modbus", "s7"]


def port_of(endpoint: str) -> int:
    port = urlsplit(endpoint).port
    assert port is not None, endpoint
    return port


@contextmanager
def occupied(port: int) -> Iterator[None]:
    """`port` on 127.0.0.1 listened on by someone else while the block runs."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", port))
        s.listen(1)
        yield


@pytest.fixture(autouse=True)
def _quiet_asyncua(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.CRITICAL, logger="asyncua")  # its own traceback of the failed bind


@pytest.mark.parametrize("protocol", PROTOCOLS)
async def test_a_picked_port_taken_before_the_bind_is_picked_again(protocol: str) -> None:
    sim = make_sim_controller(protocol)
    taken = port_of(sim.endpoint)
    with occupied(taken):
        await sim.start()
        try:
            assert port_of(sim.endpoint) != taken
            await sim.publish({"bearing": 23.5})
            driver = open_driver(protocol, sim.endpoint, sim.channels, sim.outputs_map,
                                 timeout_s=5.0)
            try:
                await asyncio.wait_for(driver.connect(), 30.0)
                got = await asyncio.wait_for(driver.read(["bearing"]), 30.0)
                assert got["bearing"].value == pytest.approx(23.5, abs=0.01)
            finally:
                await driver.close()
        finally:
            await sim.stop()


@pytest.mark.parametrize("protocol", PROTOCOLS)
async def test_a_named_port_that_is_taken_fails_the_start(protocol: str) -> None:
    port = port_of(make_sim_controller(protocol).endpoint)
    sim = make_sim_controller(protocol, port=port)
    with occupied(port), pytest.raises(Exception):  # noqa: B017  (each library its own error)
        await sim.start()
    assert port_of(sim.endpoint) == port
