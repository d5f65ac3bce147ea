"""OPC UA specifics beyond the shared contract: one Read per cycle, writes
with the node's own type, status codes as quality, write refusals, timeouts
and teardown. One simulated server per module (it takes a second to build)."""

from __future__ import annotations

import asyncio
import logging
import math
from collections.abc import AsyncIterator

import pytest
import pytest_asyncio
from asyncua import ua
from asyncua.client.client import Client
from asyncua.ua.uaerrors import BadTypeMismatch

from drivers.addresses import OpcUaAddress, S7Address
from drivers.backoff import Backoff
from drivers.base import Quality
from drivers.errors import BadAddress, ConnectionLost, ControllerTimeout, WriteRejected
from drivers.opcua import OpcUaDriver
from drivers.sim import CHANNELS
from drivers.sim.opcua_server import OpcUaSimController, node_id

pytestmark = pytest.mark.asyncio(loop_scope="module")

#: a bound on "fast" for calls that must not hang (not a speed assertion)
FAST_S = 3.0


@pytest_asyncio.fixture(loop_scope="module", scope="module")
async def sim() -> AsyncIterator[OpcUaSimController]:
    controller = OpcUaSimController()
    await controller.start()
    try:
        yield controller
    finally:
        await controller.stop()


def _driver(sim: OpcUaSimController, *, timeout_s: float = 0.5,
            channels: dict[str, OpcUaAddress] | None = None,
            outputs: dict[str, OpcUaAddress] | None = None) -> OpcUaDriver:
    return OpcUaDriver(
        sim.endpoint,
        channels if channels is not None else dict(sim.channels),  # type: ignore[arg-type]
        outputs if outputs is not None else dict(sim.outputs_map),  # type: ignore[arg-type]
        timeout_s=timeout_s, backoff=Backoff(initial_s=0.02, cap_s=0.1))


async def test_one_read_request_per_cycle(sim: OpcUaSimController) -> None:
    driver = _driver(sim)
    try:
        await driver.connect()
        reads_before, writes_before = sim.read_requests, sim.write_requests
        for cycle in range(5):
            samples = await driver.read(list(CHANNELS))
            assert set(samples) == set(CHANNELS)
            await driver.write({"offset": float(cycle), "heartbeat": cycle, "status": 1})
    finally:
        await driver.close()
    assert sim.read_requests - reads_before == 5
    assert sim.write_requests - writes_before == 5


async def test_float_and_double_nodes_written_with_their_own_type(
        sim: OpcUaSimController) -> None:
    assert sim.types["offset"] is ua.VariantType.Float
    assert sim.types["enc_double"] is ua.VariantType.Double
    outputs = {"offset": sim.outputs_map["offset"], "enc_double": sim.encodings["enc_double"]}
    driver = _driver(sim, outputs=outputs)  # type: ignore[arg-type]
    try:
        await driver.write({"offset": -12.25, "enc_double": 0.1})
        back = await driver.read(["offset", "enc_double"])
    finally:
        await driver.close()
    assert back["offset"].value == -12.25
    assert back["enc_double"].value == 0.1  # a Double keeps every bit
    assert await sim.value("offset") == -12.25


async def test_plain_float_to_float_node_is_the_trap_we_avoid(
        sim: OpcUaSimController) -> None:
    """The bare client sends a Python float as Double: BadTypeMismatch."""
    # generous request and liveness-probe times: a loaded PC answers late, never wrong
    client = Client(sim.endpoint, timeout=60, watchdog_intervall=60)
    await client.connect()
    try:
        with pytest.raises(BadTypeMismatch):
            await client.get_node(node_id("offset")).write_value(1.5)
    finally:
        await client.disconnect()


async def test_float_channel_reads_back(sim: OpcUaSimController) -> None:
    assert sim.types["power_kw"] is ua.VariantType.Float
    await sim.publish({"power_kw": 7.25, "bearing": 30.1})
    driver = _driver(sim)
    try:
        samples = await driver.read(["power_kw", "bearing"])
    finally:
        await driver.close()
    assert samples["power_kw"].value == 7.25
    assert samples["bearing"].value == 30.1


async def test_status_code_becomes_quality(sim: OpcUaSimController) -> None:
    await sim.publish({"motor": 40.0, "column": 21.0})
    driver = _driver(sim)
    try:
        await sim.publish_status("motor", bad=True)
        await sim.publish_status("column", bad=False, uncertain=True)
        samples = await driver.read(["motor", "column", "table"])
        assert samples["motor"].quality is Quality.BAD
        assert samples["column"].quality is Quality.UNCERTAIN
        assert samples["column"].value == 21.0
        assert samples["table"].quality is Quality.GOOD
        await sim.publish_status("motor", bad=False)
        await sim.publish_status("column", bad=False)
        await sim.publish({"motor": 41.0})
        again = await driver.read(["motor", "column"])
    finally:
        await driver.close()
    assert again["motor"].quality is Quality.GOOD
    assert again["motor"].value == 41.0
    assert again["column"].quality is Quality.GOOD


async def test_unknown_node_in_a_multi_read_is_bad_address(sim: OpcUaSimController) -> None:
    missing = OpcUaAddress(node="ns=2;s=Machine.Nope")
    channels = {"bearing": sim.channels["bearing"], "ghost": missing}
    driver = _driver(sim, channels=channels)  # type: ignore[arg-type]
    try:
        with pytest.raises(BadAddress, match=r"BadNodeIdUnknown.*ghost.*Machine\.Nope") as err:
            await driver.read(["bearing", "ghost"])
        assert err.value.channels == ("ghost",)
        assert driver.connected  # an address error is not a link error
        assert (await driver.read(["bearing"]))["bearing"].quality is Quality.GOOD
    finally:
        await driver.close()


async def test_read_only_node_write_is_permanent_rejection(sim: OpcUaSimController) -> None:
    outputs = {"ro": sim.channels["bearing"]}
    driver = _driver(sim, outputs=outputs)  # type: ignore[arg-type]
    try:
        with pytest.raises(WriteRejected, match=r"BadNotWritable|BadUserAccessDenied") as err:
            await driver.write({"ro": 1.0})
    finally:
        await driver.close()
    assert err.value.permanent
    assert err.value.channels == ("ro",)


async def test_unknown_output_node_is_bad_address(sim: OpcUaSimController) -> None:
    outputs = {"offset": sim.outputs_map["offset"],
               "gone": OpcUaAddress(node="ns=2;s=Machine.Gone")}
    driver = _driver(sim, outputs=outputs)  # type: ignore[arg-type]
    try:
        await driver.write({"offset": 1.0})  # the good output still works
        with pytest.raises(BadAddress, match="Gone"):
            await driver.write({"gone": 1.0})
    finally:
        await driver.close()


@pytest.mark.parametrize(("name", "value"), [
    ("status", -1.0), ("status", 70000.0), ("heartbeat", 2.0**32), ("offset", math.nan),
    ("offset", 1e39),
])
async def test_unencodable_value_is_bad_address(sim: OpcUaSimController, name: str,
                                                value: float) -> None:
    driver = _driver(sim)
    try:
        with pytest.raises(BadAddress):
            await driver.write({name: value})
    finally:
        await driver.close()


async def test_hung_server_times_out_fast_and_recovers(sim: OpcUaSimController) -> None:
    driver = _driver(sim, timeout_s=0.2)
    try:
        await driver.connect()
        sim.set_latency(5.0)
        with pytest.raises(ControllerTimeout):
            await asyncio.wait_for(driver.read(["ambient"]), FAST_S)
        assert not driver.connected
        with pytest.raises((ControllerTimeout, ConnectionLost)):
            await asyncio.wait_for(driver.write({"offset": 1.0}), FAST_S)
        sim.set_latency(0.0)
        for _ in range(100):
            try:
                await asyncio.wait_for(driver.read(["ambient"]), FAST_S)
                break
            except ConnectionLost:
                await asyncio.sleep(0.02)
        assert driver.connected
    finally:
        sim.set_latency(0.0)
        await driver.close()


def _client_tasks() -> set[asyncio.Task[object]]:
    return {t for t in asyncio.all_tasks()
            if getattr(t.get_coro(), "__qualname__", "").startswith("Client.")}


async def test_lost_link_leaves_no_client_tasks(sim: OpcUaSimController) -> None:
    driver = _driver(sim)
    try:
        await driver.read(["ambient"])
        assert _client_tasks()  # asyncua's supervisor/watchdog/renew tasks are running
        await sim.restart()
        with pytest.raises(ConnectionLost):
            await asyncio.wait_for(driver.read(["ambient"]), FAST_S)
        assert not driver.connected
        await asyncio.sleep(0)
        assert not _client_tasks()
    finally:
        await driver.close()
    assert not _client_tasks()


async def test_fails_fast_while_backing_off(sim: OpcUaSimController) -> None:
    backoff = Backoff(initial_s=60.0, cap_s=60.0)
    driver = OpcUaDriver("opc.tcp://127.0.0.1:1", dict(sim.channels),  # type: ignore[arg-type]
                         {}, timeout_s=0.2, backoff=backoff)
    try:
        with pytest.raises(ConnectionLost, match="cannot connect"):
            await driver.read(["ambient"])
        with pytest.raises(ConnectionLost, match="next reconnect"):
            await driver.read(["ambient"])
    finally:
        await driver.close()
    assert backoff.failures == 1


async def test_config_errors_are_refused_at_construction() -> None:
    with pytest.raises(TypeError, match="OpcUaAddress"):
        OpcUaDriver("opc.tcp://127.0.0.1:4840",
                    {"a": S7Address(db=1, offset=0)}, {})  # type: ignore[dict-item]
    with pytest.raises(ValueError, match=r"opc\.tcp"):
        OpcUaDriver("http://127.0.0.1:4840", {}, {})


async def test_the_unsecured_simulated_server_starts_without_asyncua_warnings(
        caplog: pytest.LogCaptureFixture) -> None:
    """`compd sim` printed asyncua's "No signing policy available…" at every start."""
    caplog.set_level(logging.WARNING, logger="asyncua")
    sim = OpcUaSimController()
    await sim.start()
    try:
        assert sim.endpoint.startswith("opc.tcp://127.0.0.1:")
    finally:
        await sim.stop()
    warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert warnings == []
