"""An OPC UA connect is bounded by `connect_timeout_s` as a whole, not each of its
round trips by the request timeout `timeout_s`: a secure channel and a session are
several requests, with RSA work on both sides under security, and a controller (or
a loaded test machine) may answer one of them slower than a cycle's read must be.
With each handshake request held longer than `timeout_s` the connect failed as a
timeout, again at every attempt, however long `connect_timeout_s` was; under load
it turned a wrong password's refusal into a timeout (tests/faults/test_security.py).

The real driver through `tests.faults.proxy.FaultProxy` to the simulated server:
each of a connection's first client -> server chunks (the handshake) is held
`HOLD_S`, longer than the request timeout; later requests pass at once."""

from __future__ import annotations

from urllib.parse import urlsplit

import pytest

from drivers.backoff import Backoff
from drivers.opcua import OpcUaDriver
from drivers.sim import CHANNELS
from drivers.sim.opcua_server import OpcUaSimController
from tests.faults.proxy import FaultProxy

TIMEOUT_S = 0.1
#: each handshake request's hold: longer than a request may take
HOLD_S = 3 * TIMEOUT_S
#: hello, secure channel, session, activation, the outputs' types
HANDSHAKE_CHUNKS = 5
CONNECT_TIMEOUT_S = 30.0


async def test_a_handshake_slower_than_a_request_connects_within_the_connect_timeout(
        ) -> None:
    sim = OpcUaSimController()
    await sim.start()
    parts = urlsplit(sim.endpoint)
    assert parts.hostname is not None and parts.port is not None
    proxy = FaultProxy(parts.hostname, parts.port)
    await proxy.start()
    proxy.slow_start(HOLD_S, HANDSHAKE_CHUNKS)
    driver = OpcUaDriver(
        parts._replace(netloc=f"{proxy.host}:{proxy.port}").geturl(),
        dict(sim.channels), dict(sim.outputs_map),  # type: ignore[arg-type]
        timeout_s=TIMEOUT_S, connect_timeout_s=CONNECT_TIMEOUT_S,
        backoff=Backoff(initial_s=0.02, cap_s=0.1))
    try:
        await sim.publish({"bearing": 21.5})
        await driver.connect()
        assert proxy.connections_accepted == 1  # one handshake, not one per request
        got = await driver.read(list(CHANNELS))
        assert got["bearing"].value == pytest.approx(21.5)
        # once connected, the client's own request timeout is `timeout_s` again
        client = driver._link.session
        assert client is not None and client.uaclient.protocol is not None
        assert client.uaclient.protocol.timeout == TIMEOUT_S
    finally:
        await driver.close()
        await proxy.stop()
        await sim.stop()
