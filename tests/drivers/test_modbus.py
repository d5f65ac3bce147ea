"""Modbus driver against the pymodbus simulated controller (and a silent
TCP peer): request counts, word orders, scale ranges, exception codes,
timeouts, backoff. Real sockets on 127.0.0.1 throughout."""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator

import pytest
from pymodbus.pdu import ModbusPDU

from drivers.addresses import ModbusAddress, OpcUaAddress
from drivers.backoff import Backoff
from drivers.base import Quality
from drivers.errors import (
    BadAddress,
    ConnectionLost,
    ControllerTimeout,
    DriverError,
    WriteRejected,
)
from drivers.factory import open_driver
from drivers.modbus import ModbusDriver, parse_endpoint
from drivers.modbus_codec import ValueOutOfRangeError
from drivers.sim import CHANNELS
from drivers.sim.modbus_server import ENCODINGS, OUTPUTS, ModbusSimController
from drivers.sim.ports import free_tcp_port
from drivers.sim.registry import make_sim_controller

FAST_S = 5.0


@pytest.fixture
async def sim() -> AsyncIterator[ModbusSimController]:
    controller = ModbusSimController(input_registers=300, holding_registers=300)
    await controller.start()
    try:
        yield controller
    finally:
        await controller.stop()


def driver_for(sim: ModbusSimController, channels: dict[str, ModbusAddress] | None = None,
               timeout_s: float = 0.5, backoff: Backoff | None = None) -> ModbusDriver:
    return ModbusDriver(sim.endpoint, dict(sim.channels) if channels is None else channels,
                        {**OUTPUTS, **ENCODINGS}, timeout_s=timeout_s,
                        backoff=backoff or Backoff(0.02, 0.2))


def reads(sim: ModbusSimController) -> list[tuple[int, int, int]]:
    return [(r.function_code, r.address, r.count) for r in sim.requests
            if r.function_code in (3, 4)]


def writes(sim: ModbusSimController) -> list[tuple[int, int, int]]:
    return [(r.function_code, r.address, r.count) for r in sim.requests
            if r.function_code in (6, 16)]


# -- construction -------------------------------------------------------------

@pytest.mark.parametrize(("endpoint", "expected"), [
    ("modbus://127.0.0.1:5020", ("127.0.0.1", 5020)),
    ("127.0.0.1:5020", ("127.0.0.1", 5020)),
    ("modbus://plc.local", ("plc.local", 502)),
    ("tcp://[::1]:1502", ("::1", 1502)),
])
def test_endpoint_forms(endpoint: str, expected: tuple[str, int]) -> None:
    assert parse_endpoint(endpoint) == expected


@pytest.mark.parametrize("endpoint", ["", "modbus://:502", "host:port", "host:70000"])
def test_bad_endpoint_is_refused(endpoint: str) -> None:
    with pytest.raises(ValueError, match="Modbus TCP endpoint"):
        parse_endpoint(endpoint)


def test_factory_and_registry_build_modbus() -> None:
    sim = make_sim_controller("modbus")
    assert isinstance(sim, ModbusSimController)
    driver = open_driver("modbus", sim.endpoint, sim.channels, sim.outputs_map)
    assert isinstance(driver, ModbusDriver)
    assert driver.port == sim.port


def test_foreign_or_read_only_addresses_are_refused() -> None:
    with pytest.raises(BadAddress, match="bearing"):
        ModbusDriver("127.0.0.1:502", {"bearing": OpcUaAddress(node="ns=2;s=B")}, {})
    with pytest.raises(BadAddress, match="read-only"):
        ModbusDriver("127.0.0.1:502", {}, {
            "offset": ModbusAddress(kind="input", address=0)})


# -- block reads ----------------------------------------------------------------

async def test_all_channels_in_one_request(sim: ModbusSimController) -> None:
    driver = driver_for(sim)
    try:
        before_s = time.time()
        samples = await driver.read(list(CHANNELS))
        after_s = time.time()
    finally:
        await driver.close()
    assert reads(sim) == [(4, 0, 12)]
    assert all(s.quality is Quality.GOOD for s in samples.values())
    assert all(before_s <= s.timestamp_s <= after_s for s in samples.values())


async def test_channels_and_outputs_one_request_per_kind(sim: ModbusSimController) -> None:
    driver = driver_for(sim)
    try:
        await driver.read([*CHANNELS, "offset", "heartbeat", "status"])
        await driver.read([*CHANNELS, "offset", "heartbeat", "status"])
    finally:
        await driver.close()
    assert sorted(reads(sim)) == [(3, 0, 4), (3, 0, 4), (4, 0, 12), (4, 0, 12)]


async def test_a_read_sends_the_requests_built_with_its_plan(
        sim: ModbusSimController, monkeypatch: pytest.MonkeyPatch) -> None:
    """Each span's request object is built once, with the plan, and sent again on
    every read (a fresh transaction id each time); the values still come back."""
    driver = driver_for(sim)
    names = [*CHANNELS, "offset"]
    sent: list[ModbusPDU] = []
    try:
        await driver.connect()
        client = driver._link.session
        assert client is not None
        execute = client.execute

        def spy(no_response_expected: bool, request: ModbusPDU) -> object:
            sent.append(request)
            return execute(no_response_expected, request)

        monkeypatch.setattr(client, "execute", spy)
        await driver.read(names)
        first = [(r, r.transaction_id) for r in sent]
        sent.clear()
        await sim.publish({"bearing": 25.5})
        samples = await driver.read(names)
    finally:
        await driver.close()
    assert len(first) == 2 and [r for r, _ in first] == sent
    assert all(a is b for (a, _), b in zip(first, sent, strict=True))
    assert all(r.transaction_id != tid for r, tid in first)
    assert samples["bearing"].value == pytest.approx(25.5)
    assert sorted(reads(sim)) == [(3, 0, 2), (3, 0, 2), (4, 0, 12), (4, 0, 12)]


async def test_far_apart_registers_split_and_125_cap(sim: ModbusSimController) -> None:
    channels = {
        "a": ModbusAddress(kind="input", address=0, type="int16"),
        "b": ModbusAddress(kind="input", address=5, type="int16"),      # gap 4: merged
        "c": ModbusAddress(kind="input", address=100, type="int16"),    # far: own request
        "d": ModbusAddress(kind="input", address=224, type="float32"),  # 100..225 > 125
    }
    await sim.publish({})
    sim.set_raw("input", 224, [0x3FC0, 0])
    driver = driver_for(sim, channels)
    try:
        samples = await driver.read(list(channels))
    finally:
        await driver.close()
    assert reads(sim) == [(4, 0, 6), (4, 100, 1), (4, 224, 2)]
    assert samples["d"].value == 1.5


async def test_word_orders_from_raw_registers(sim: ModbusSimController) -> None:
    channels = {
        "big": ModbusAddress(kind="holding", address=20, type="float32"),
        "little": ModbusAddress(kind="holding", address=22, type="float32",
                                word_order="little"),
        "i32_big": ModbusAddress(kind="holding", address=24, type="int32"),
        "i32_little": ModbusAddress(kind="holding", address=26, type="int32",
                                    word_order="little"),
    }
    sim.set_raw("holding", 20, [0xC2F7, 0x0000, 0x0000, 0xC2F7,   # -123.5 both ways
                                0xFFFE, 0x1DC0, 0x1DC0, 0xFFFE])  # -123456 both ways
    driver = driver_for(sim, channels)
    try:
        samples = await driver.read(list(channels))
    finally:
        await driver.close()
    assert samples["big"].value == -123.5
    assert samples["little"].value == -123.5
    assert samples["i32_big"].value == -123456
    assert samples["i32_little"].value == -123456
    assert reads(sim) == [(3, 20, 8)]


async def test_sentinels_pass_through(sim: ModbusSimController) -> None:
    sim.set_raw("input", 0, [0x7FFF, 0x8000])  # open / shorted Pt100 on a PLC card
    driver = driver_for(sim)
    try:
        samples = await driver.read(["bearing", "motor"])
    finally:
        await driver.close()
    assert samples["bearing"].value == pytest.approx(3276.7)
    assert samples["motor"].value == pytest.approx(-3276.8)
    assert samples["bearing"].quality is Quality.GOOD


# -- writes and scale ranges --------------------------------------------------------

async def test_offset_heartbeat_status_in_one_write(sim: ModbusSimController) -> None:
    driver = driver_for(sim)
    try:
        await driver.write({"status": 2, "offset": -8.25, "heartbeat": 65535})
    finally:
        await driver.close()
    assert writes(sim) == [(16, 0, 4)]
    assert await sim.outputs() == {"offset": -8.25, "heartbeat": 65535, "status": 2}


async def test_out_of_range_write_sends_nothing(sim: ModbusSimController) -> None:
    driver = driver_for(sim)
    try:
        with pytest.raises(ValueOutOfRangeError, match="enc_i16_centi"):
            await driver.write({"enc_i16_centi": 327.68})
        with pytest.raises(ValueError, match="heartbeat"):
            await driver.write({"offset": 1.0, "heartbeat": -1})
        await driver.write({"enc_i16_centi": -327.68, "enc_i32_milli": 2147483.647})
        back = await driver.read(["enc_i16_centi", "enc_i32_milli"])
    finally:
        await driver.close()
    assert writes(sim) == [(16, 12, 2), (16, 15, 1)]  # 14 lies between: two requests
    assert back["enc_i16_centi"].value == pytest.approx(-327.68)
    assert back["enc_i32_milli"].value == pytest.approx(2147483.647)


# -- exception responses ----------------------------------------------------------

async def test_illegal_address_names_the_channel(sim: ModbusSimController) -> None:
    sim.inject_exception("input", 5, 2, on="read")  # spindle_rpm
    driver = driver_for(sim)
    try:
        with pytest.raises(BadAddress) as caught:
            await driver.read(list(CHANNELS))
        # the rest of the block is still readable: the driver now reads item by item
        samples = await driver.read(["bearing", "power_kw"])
    finally:
        await driver.close()
    assert caught.value.channels == ("spindle_rpm",)
    assert "unit1/input/5:uint16" in str(caught.value)
    assert "code 2" in str(caught.value)
    assert set(samples) == {"bearing", "power_kw"}


async def test_refused_gap_register_is_read_around(sim: ModbusSimController) -> None:
    channels = {"a": ModbusAddress(kind="holding", address=40, type="int16"),
                "b": ModbusAddress(kind="holding", address=44, type="int16")}
    sim.set_raw("holding", 40, [7, 0, 0, 0, 9])
    sim.inject_exception("holding", 42, 2)  # a hole in the PLC's map, between them
    driver = driver_for(sim, channels)
    try:
        first = await driver.read(["a", "b"])
        second = await driver.read(["a", "b"])
    finally:
        await driver.close()
    assert first["a"].value == 7 and first["b"].value == 9
    assert second["b"].value == 9
    assert reads(sim) == [(3, 40, 5), (3, 40, 1), (3, 44, 1), (3, 40, 1), (3, 44, 1)]


async def test_busy_read_is_a_driver_error_not_bad_address(sim: ModbusSimController) -> None:
    sim.inject_exception("input", 0, 6, count=12, on="read")
    driver = driver_for(sim)
    try:
        with pytest.raises(DriverError, match="code 6") as caught:
            await driver.read(["bearing"])
    finally:
        await driver.close()
    assert not isinstance(caught.value, BadAddress)
    assert caught.value.channels == ("bearing",)


@pytest.mark.parametrize(("code", "permanent"), [
    (1, True), (2, True), (3, True), (4, False), (5, False), (6, False)])
async def test_write_exception_codes(sim: ModbusSimController, code: int,
                                     permanent: bool) -> None:
    sim.inject_exception("holding", 0, code, count=2, on="write")
    driver = driver_for(sim)
    try:
        with pytest.raises(WriteRejected) as caught:
            await driver.write({"offset": 5.0})
        samples = await driver.read(["offset"])  # the link survives a refusal
    finally:
        await driver.close()
    assert caught.value.permanent is permanent
    assert caught.value.channels == ("offset",)
    assert caught.value.address == OUTPUTS["offset"].describe()
    assert f"code {code}" in str(caught.value)
    assert writes(sim) == [(16, 0, 2)]  # sent once, never retried
    assert samples["offset"].value == 0.0


# -- timeouts, lost links and backoff --------------------------------------------------

class _Silent(asyncio.Protocol):
    """Accepts, reads, never answers (a hung controller's TCP stack)."""

    def __init__(self, received: list[bytes], transports: list[asyncio.Transport]) -> None:
        self.received = received
        self.transports = transports

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        if isinstance(transport, asyncio.Transport):
            self.transports.append(transport)

    def data_received(self, data: bytes) -> None:
        self.received.append(data)


async def test_silent_server_times_out_fast_and_write_is_not_resent() -> None:
    received: list[bytes] = []
    transports: list[asyncio.Transport] = []
    loop = asyncio.get_running_loop()
    server = await loop.create_server(lambda: _Silent(received, transports), "127.0.0.1", 0)
    port = server.sockets[0].getsockname()[1]
    outputs = dict(OUTPUTS)
    driver = ModbusDriver(f"127.0.0.1:{port}", {}, outputs, timeout_s=0.2,
                          backoff=Backoff(0.01, 0.05))
    try:
        with pytest.raises(ControllerTimeout) as caught:
            await asyncio.wait_for(driver.read(["offset"]), FAST_S)
        assert caught.value.channels == ("offset",)
        assert not driver.connected
        await asyncio.sleep(0.06)  # backoff elapsed: the next call reconnects
        received.clear()
        with pytest.raises(ControllerTimeout):
            await asyncio.wait_for(driver.write({"offset": 1.0}), FAST_S)
        await asyncio.sleep(0.3)  # longer than the timeout: a resend would show up
        frames = b"".join(received)
        assert len(frames) == 7 + 6 + 4  # one MBAP header + FC16 header + 2 registers
        assert frames[7] == 16
    finally:
        await driver.close()
        server.close()
        for transport in transports:
            transport.close()
        await server.wait_closed()


async def test_hung_sim_times_out_then_recovers(sim: ModbusSimController) -> None:
    driver = driver_for(sim, timeout_s=0.2, backoff=Backoff(0.01, 0.05))
    try:
        await driver.read(["bearing"])
        sim.set_hang(True)
        with pytest.raises(ControllerTimeout):
            await asyncio.wait_for(driver.read(["bearing"]), FAST_S)
        sim.set_hang(False)
        await sim.publish({"bearing": 25.5})
        for _ in range(100):
            try:
                samples = await driver.read(["bearing"])
                break
            except ConnectionLost:
                await asyncio.sleep(0.02)
        assert samples["bearing"].value == pytest.approx(25.5)
    finally:
        await driver.close()


async def test_backoff_gates_reconnect_attempts() -> None:
    now = [1000.0]
    backoff = Backoff(initial_s=1.0, cap_s=4.0, clock=lambda: now[0])
    port = free_tcp_port()
    sim = ModbusSimController(port=port)
    driver = ModbusDriver(sim.endpoint, dict(sim.channels), dict(sim.outputs_map),
                          timeout_s=0.5, backoff=backoff)
    try:
        with pytest.raises(ConnectionLost, match="cannot connect"):
            await driver.read(["ambient"])      # attempted, refused
        await sim.start()
        with pytest.raises(ConnectionLost, match="backing off"):
            await driver.read(["ambient"])      # not yet due: fails without trying
        assert sim.requests == []
        now[0] += 1.0
        await driver.read(["ambient"])          # due: reconnects
        assert backoff.failures == 0
        await sim.stop()
        with pytest.raises(ConnectionLost):
            await asyncio.wait_for(driver.read(["ambient"]), FAST_S)
        with pytest.raises(ConnectionLost, match="backing off"):
            await driver.write({"offset": 1.0})
    finally:
        await driver.close()
        await sim.stop()


async def test_explicit_connect_failure_is_connection_lost() -> None:
    driver = ModbusDriver(f"127.0.0.1:{free_tcp_port()}", {}, {}, timeout_s=0.2)
    try:
        with pytest.raises(ConnectionLost) as caught:
            await asyncio.wait_for(driver.connect(), FAST_S)
        assert "127.0.0.1" in str(caught.value)
        assert not driver.connected
    finally:
        await driver.close()
