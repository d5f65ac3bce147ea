"""S7 driver against python-snap7's server on 127.0.0.1 (no mocks)."""

from __future__ import annotations

import asyncio
import socket
import threading
from collections.abc import AsyncIterator, Iterator

import pytest

from drivers.addresses import S7Address
from drivers.backoff import Backoff
from drivers.errors import BadAddress, ConnectionLost, ControllerTimeout
from drivers.s7 import S7Driver, parse_endpoint
from drivers.s7_codec import encode, read_spans, write_runs
from drivers.sim.s7_server import CHANNELS, ENCODINGS, OUTPUTS, S7SimController

READ, WRITE = 0x04, 0x05


@pytest.fixture
async def sim() -> AsyncIterator[S7SimController]:
    controller = S7SimController()
    await controller.start()
    try:
        yield controller
    finally:
        await controller.stop()


def _driver(sim: S7SimController, timeout_s: float = 0.5, **kw: object) -> S7Driver:
    return S7Driver(sim.endpoint, {**CHANNELS, **ENCODINGS}, {**OUTPUTS, **ENCODINGS},
                    timeout_s=timeout_s, backoff=Backoff(0.01, 0.05), **kw)  # type: ignore[arg-type]


async def test_one_read_request_per_db(sim: S7SimController) -> None:
    drv = _driver(sim)
    try:
        await drv.connect()
        before = sim.request_counts().get(READ, 0)
        values = await drv.read([*CHANNELS, "enc_real"])  # DB1 and DB3
        assert sim.request_counts()[READ] - before == 2
        assert set(values) == {*CHANNELS, "enc_real"}
        before_w = sim.request_counts().get(WRITE, 0)
        await drv.write({"offset": 1.5, "heartbeat": 2, "status": 3})  # adjacent in DB2
        assert sim.request_counts()[WRITE] - before_w == 1
    finally:
        await drv.close()


async def test_values_and_pt100_sentinels_pass_through(sim: S7SimController) -> None:
    await sim.publish({"bearing": 3276.7, "motor": -3276.8, "column": 21.4,
                       "spindle_rpm": 15000, "power_kw": 7.25, "error_um": -3.5})
    drv = _driver(sim)
    try:
        got = await drv.read(["bearing", "motor", "column", "spindle_rpm", "power_kw", "error_um"])
    finally:
        await drv.close()
    # raw 32767 / -32768 are what a Pt100 card reports open / shorted: not clamped
    assert got["bearing"].value == pytest.approx(3276.7)
    assert got["motor"].value == pytest.approx(-3276.8)
    assert got["column"].value == pytest.approx(21.4)
    assert got["spindle_rpm"].value == 15000
    assert got["power_kw"].value == 7.25
    assert got["error_um"].value == -3.5


async def test_encodings_round_trip_and_range_refused(sim: S7SimController) -> None:
    drv = _driver(sim)
    try:
        vals = {"enc_int": -12.3, "enc_dint_milli": -1234.567, "enc_real": -0.125,
                "enc_word": 65535, "offset": -42.5}
        await drv.write(vals)
        got = await drv.read(list(vals))
        for name, v in vals.items():
            assert got[name].value == pytest.approx(v, abs=1e-3)
        assert await sim.read_back("enc_dint_milli") == pytest.approx(-1234.567)
        with pytest.raises(BadAddress) as info:
            await drv.write({"enc_word": -1})
        assert info.value.channels == ("enc_word",) and info.value.address == "DB3.10:WORD"
        with pytest.raises(BadAddress):
            await drv.write({"enc_int": 4000.0})  # raw 40000 does not fit an INT
    finally:
        await drv.close()


async def test_missing_db_and_out_of_range_name_the_channel(sim: S7SimController) -> None:
    bad = {"ghost": S7Address(db=42, offset=0, type="REAL"),
           "past_end": S7Address(db=1, offset=38, type="DINT")}  # DB1 is 40 bytes
    drv = S7Driver(sim.endpoint, {**CHANNELS, **bad}, bad, timeout_s=0.5)
    try:
        for name, addr in bad.items():
            with pytest.raises(BadAddress) as info:
                await drv.read(["bearing", name])
            assert (info.value.channels, info.value.address) == ((name,), addr.describe())
        with pytest.raises(BadAddress) as winfo:
            await drv.write({"ghost": 1.0})
        assert winfo.value.channels == ("ghost",)
        assert (await drv.read(["bearing"]))["bearing"].quality.value == "good"
    finally:
        await drv.close()


@pytest.fixture
def silent_server() -> Iterator[int]:
    """A TCP server on 127.0.0.1 that accepts and never says a word."""
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(8)
    held: list[socket.socket] = []
    stop = threading.Event()

    def accept() -> None:
        srv.settimeout(0.05)
        while not stop.is_set():
            try:
                held.append(srv.accept()[0])
            except TimeoutError:
                continue

    t = threading.Thread(target=accept, daemon=True)
    t.start()
    yield srv.getsockname()[1]
    stop.set()
    t.join()
    for s in held:
        s.close()
    srv.close()


async def test_hung_server_times_out_instead_of_snap7s_five_seconds(silent_server: int) -> None:
    drv = S7Driver(f"s7://127.0.0.1:{silent_server}", CHANNELS, OUTPUTS, timeout_s=0.1,
                   backoff=Backoff(0.01, 0.02))
    try:
        for _ in range(3):  # each attempt frees the worker thread before the next
            with pytest.raises(ControllerTimeout):
                await drv.read(["bearing"])
            await asyncio.sleep(0.03)
        assert not drv.connected
    finally:
        await drv.close()


async def test_frozen_cpu_times_out_then_same_driver_recovers(sim: S7SimController) -> None:
    # The connected socket keeps snap7's 5 s timeout unless the driver applies
    # its own; then the single worker thread would still be blocked when the
    # CPU answers again and the read after unfreezing would time out too.
    drv = _driver(sim, timeout_s=0.15)
    try:
        await drv.read(["bearing"])
        sim.freeze(True)
        with pytest.raises(ControllerTimeout):
            await drv.read(["bearing"])
        sim.freeze(False)
        await asyncio.sleep(0.06)
        got = await drv.read(["bearing"])
        assert "bearing" in got and drv.connected
    finally:
        await drv.close()


async def test_restart_is_reconnected_by_the_same_driver(sim: S7SimController) -> None:
    drv = _driver(sim)
    try:
        await drv.write({"offset": 5.0})
        await sim.stop()
        with pytest.raises(ConnectionLost):
            await drv.read(["bearing"])
        await sim.forget_outputs()
        await sim.start()
        for _ in range(100):
            try:
                await drv.read(["offset"])
                break
            except ConnectionLost:
                await asyncio.sleep(0.01)
        assert drv.connected
        assert (await drv.read(["offset"]))["offset"].value == 0.0  # the restart lost it
        await drv.write({"offset": 6.0})
        assert (await sim.outputs())["offset"] == 6.0
    finally:
        await drv.close()


async def test_close_is_idempotent_and_calls_after_close_fail(sim: S7SimController) -> None:
    drv = _driver(sim)
    await drv.read(["bearing"])
    await drv.close()
    await drv.close()
    with pytest.raises(ConnectionLost):
        await drv.read(["bearing"])


def test_endpoint_and_planning() -> None:
    assert parse_endpoint("s7://10.0.0.5") == ("10.0.0.5", 102)
    assert parse_endpoint("s7://127.0.0.1:1102") == ("127.0.0.1", 1102)
    with pytest.raises(ValueError, match="S7 endpoint"):
        parse_endpoint("opc.tcp://x:4840")
    spans = read_spans(CHANNELS)
    assert [(s.db, s.start, s.size) for s in spans] == [(1, 0, 26)]
    runs = write_runs([("status", OUTPUTS["status"]), ("offset", OUTPUTS["offset"])])
    assert [(r.start, r.names) for r in runs] == [(0, ("offset",)), (8, ("status",))]
    assert encode(S7Address(db=1, offset=0, type="INT", scale=0.1), -0.04) == b"\x00\x00"
