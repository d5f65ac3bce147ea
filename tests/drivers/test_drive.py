"""The HIL drive loop (`drivers.sim.drive`) against the simulated controllers:
the plant writes its sensors through our real drivers into the controller's
memory and reads back an offset a second client (the daemon's stand-in) wrote
there; plus drive-map validation and the offline-safe path."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Mapping
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import pytest

from drivers.backoff import Backoff
from drivers.base import Driver
from drivers.errors import WriteRejected
from drivers.factory import open_driver
from drivers.sim.drive import (
    DRIVE_COLUMNS,
    RECORD_FIELDS,
    DriveLoop,
    drive_endpoint,
    open_drive_driver,
    write_drive_record,
)
from drivers.sim.drive_map import DriveMap, DriveMapError, load_drive_map, parse_drive_map
from drivers.sim.programs import constant
from drivers.sim.registry import make_sim_controller
from tests.configs import CONNECT_TIMEOUT_S, REQUEST_TIMEOUT_S
from tests.record_columns import read_columns as read_record
from tests.shipped import MAPS

REPO = Path(__file__).resolve().parents[2]
PROTOCOLS = ("modbus", "s7", "focas", "opcua")
TEMPERATURES = ("bearing", "motor", "column", "table", "ambient")


@asynccontextmanager
async def bench(protocol: str) -> AsyncIterator[tuple[Any, DriveMap, dict[str, Any]]]:
    """A simulated controller in the bench layout, the shipped map, and the
    driver options a client of it needs: a loaded test machine answers late, never
    "not at all" (the server runs in this process, beside the two clients), so a
    request and a connect have the lockstep runs' generous bounds, not the map's
    0.5 s (one late answer would count as a link error)."""
    options: dict[str, Any] = {"writable_channels": True} if protocol == "opcua" else {}
    sim: Any = make_sim_controller(protocol, **options)
    await sim.start()
    extra: dict[str, Any] = {"backoff": Backoff(initial_s=0.02, cap_s=0.1),
                             "timeout_s": REQUEST_TIMEOUT_S}
    if protocol == "opcua":
        extra["connect_timeout_s"] = CONNECT_TIMEOUT_S
    if protocol == "focas":
        extra["library_path"] = sim.library_path
    try:
        yield sim, load_drive_map(MAPS / f"{protocol}.toml"), extra
    finally:
        await sim.stop()
        if protocol == "focas":
            sim.close()


def _url(sim: Any) -> str:
    return str(sim.endpoint).replace("opc.tcp://", "opcua://")


def _daemon(sim: Any, drive_map: DriveMap, extra: Mapping[str, Any]) -> Driver:
    """The daemon's stand-in: writes the map's read addresses, reads its writes."""
    return open_driver(drive_map.protocol, sim.endpoint, drive_map.write, drive_map.read,
                       **extra)


# -- the loop through each protocol -------------------------------------------------


@pytest.mark.parametrize("protocol", PROTOCOLS)
async def test_plant_writes_sensors_and_applies_the_offset_the_daemon_wrote(
        protocol: str) -> None:
    async with bench(protocol) as (sim, drive_map, extra):
        driver = open_drive_driver(_url(sim), drive_map, **extra)
        drive = DriveLoop(driver, drive_map, program=constant(9_000.0, 1.0, 1.0), seed=3,
                          speedup=20_000.0, record=True)
        daemon = _daemon(sim, drive_map, extra)
        await daemon.connect()
        try:
            await drive.prime()
            for _ in range(5):
                await drive.tick()
            before = drive.latest
            assert before["offset_um"] == 0.0
            assert before["error_um"] == pytest.approx(before["growth_um"])

            await daemon.write({"offset": 12.5, "heartbeat": 7, "status": 1})
            await drive.tick()
            after = drive.latest
            assert after["offset_um"] == pytest.approx(12.5, abs=1e-6)
            assert after["error_um"] == pytest.approx(after["growth_um"] - 12.5, abs=1e-9)
            assert (after["heartbeat"], after["status"]) == (7.0, 1.0)

            await daemon.write({"offset": 25.0, "heartbeat": 8, "status": 1})
            await drive.run(until_s=120.0)  # scheduled ticks; closes the driver
            assert drive.time_s == pytest.approx(120.0)
            last = drive.latest
            assert last["offset_um"] == pytest.approx(25.0, abs=1e-6)
            assert last["error_um"] == pytest.approx(last["growth_um"] - 25.0, abs=1e-9)
            assert last["heartbeat"] == 8.0
            assert drive.link_errors == 0 and last["link_ok"] == 1.0

            # the controller's memory holds the plant's last values at the mapped addresses
            got = await daemon.read(list(drive_map.write))
            assert set(got) == set(drive_map.write)
            for name in TEMPERATURES:
                assert got[name].value == pytest.approx(last[name], abs=0.051), name
            assert got["spindle_rpm"].value == last["spindle_rpm"] == 9_000.0
            for name in ("power_kw", "growth_um", "error_um"):
                assert got[name].value == pytest.approx(last[name], rel=1e-6, abs=1e-6), name
        finally:
            await daemon.close()
            await drive.stop()

        rows = drive.history
        assert len(rows) == drive.ticks + 1 == 121
        assert [r["time_s"] for r in rows] == [float(k) for k in range(121)]
        assert rows[-1]["bearing"] > rows[0]["bearing"] + 0.5  # the spindle heated it


async def test_a_lost_link_never_stops_the_plant_and_recovers() -> None:
    async with bench("modbus") as (sim, drive_map, extra):
        drive = DriveLoop(open_drive_driver(_url(sim), drive_map, **extra), drive_map,
                          program=constant(9_000.0, 1.0, 1.0), record=True)
        daemon = _daemon(sim, drive_map, extra)
        try:
            await daemon.connect()
            await daemon.write({"offset": 4.0})
            await drive.prime()
            await drive.tick()
            await sim.stop()
            for _ in range(4):
                await drive.tick()
            assert drive.ticks == 5 and drive.time_s == 5.0
            assert drive.link_errors >= 4 and drive.last_error
            assert drive.latest["link_ok"] == 0.0
            assert drive.plant.offset_um == 4.0  # held while unreachable
            await sim.start()
            for _ in range(100):  # the driver reconnects after its backoff (real time)
                await asyncio.sleep(0.02)
                await drive.tick()
                if drive.latest["link_ok"] == 1.0:
                    break
            assert drive.latest["link_ok"] == 1.0
            assert (await sim.read_values(["offset"]))["offset"] == 4.0
            assert sim.raw("holding", 25, 1) == [9_000]
        finally:
            await daemon.close()
            await drive.driver.close()


async def test_a_permanently_refused_write_ends_the_run() -> None:
    async with bench("modbus") as (sim, drive_map, extra):
        sim.inject_exception("holding", 20, 2, on="write")  # illegal data address
        drive = DriveLoop(open_drive_driver(_url(sim), drive_map, **extra), drive_map)
        with pytest.raises(WriteRejected) as err:
            await drive.run(until_s=10.0)
        assert err.value.permanent
        assert not drive.driver.connected  # closed on the way out


async def test_read_only_opcua_channel_nodes_are_refused_for_good() -> None:
    sim: Any = make_sim_controller("opcua")  # default layout: channel nodes read-only
    await sim.start()
    try:
        drive_map = load_drive_map(MAPS / "opcua.toml")
        drive = DriveLoop(open_drive_driver(_url(sim), drive_map), drive_map)
        with pytest.raises(WriteRejected) as err:
            await drive.run(until_s=5.0)
        assert err.value.permanent
    finally:
        await sim.stop()


async def test_record_is_a_calibration_record_with_what_the_bench_saw(tmp_path: Path) -> None:
    async with bench("s7") as (sim, drive_map, extra):
        drive = DriveLoop(open_drive_driver(_url(sim), drive_map, **extra), drive_map,
                          program=constant(6_000.0, 0.5, 0.5), speedup=50_000.0, record=True)
        await sim.publish({"offset": 3.0, "heartbeat": 41})
        await drive.run(until_s=30.0)
    out = tmp_path / "run.csv"
    assert write_drive_record(out, drive.history_arrays()) == 31
    assert out.read_text().splitlines()[0] == ",".join(RECORD_FIELDS)
    rec = read_record(out)
    assert list(rec) == list(RECORD_FIELDS)
    assert set(rec["offset_um"]) == {3.0} and set(rec["heartbeat"]) == {41.0}
    assert rec["error_um"] == pytest.approx(rec["dz_um"] - 3.0, abs=2e-3)
    assert set(rec["spindle_rpm"][1:]) == {6_000.0}


# -- maps and endpoints ----------------------------------------------------------------


@pytest.mark.parametrize("protocol", PROTOCOLS)
def test_shipped_maps_load_and_map_every_plant_sensor(protocol: str) -> None:
    m = load_drive_map(MAPS / f"{protocol}.toml")
    assert m.protocol == protocol
    assert {"bearing", "motor", "column", "table", "ambient", "spindle_rpm",
            "power_kw"} <= set(m.write)
    # the per-axis temperature-compensation parameters are opt-in (commented out)
    assert set(m.read) == {"offset", "heartbeat", "status"}


_MODBUS = {"protocol": "modbus",
           "write": {"bearing": {"kind": "holding", "address": 20, "type": "int16",
                                 "scale": 0.1}},
           "read": {"offset": {"kind": "holding", "address": 0}}}


@pytest.mark.parametrize(("change", "message"), [
    ({"colour": "red"}, "colour"),
    ({"write": {"bearing": {"kind": "input", "address": 20}}}, "read-only"),
    ({"write": {"bearing": {"kind": "holding", "address": 1}}}, "overlap"),
    ({"write": {"bearing": {"db": 1, "offset": 0}}}, "not a modbus address"),
    ({"write": {"spindle_colour": {"address": 20}}}, "unknown plant channel"),
    ({"write": {}}, "at least one"),
    ({"read": {"heartbeat": {"address": 2, "type": "uint16"}}}, "read.offset is required"),
    ({"read": {"offset": {"address": 0}, "speed": {"address": 4}}}, "unknown name"),
    ({"offset_um_per_unit": 0.0}, "non-zero"),
    ({"driver": {"rack": 0}}, "do not apply to modbus"),
    ({"driver": {"timeout_s": 0}}, "timeout_s"),
])
def test_bad_maps_are_refused_naming_the_key(change: dict[str, Any], message: str) -> None:
    with pytest.raises(DriveMapError, match=message):
        parse_drive_map({**_MODBUS, **change}, "m.toml")


def test_focas_writes_only_pmc_and_defaults_kind_to_pmc() -> None:
    base = {"protocol": "focas", "read": {"offset": {"area": "D", "address": 100}}}
    m = parse_drive_map({**base, "write": {"bearing": {"area": "D", "address": 0,
                                                       "type": "word"}}})
    assert m.write["bearing"].describe() == "PMC D0:word"
    with pytest.raises(DriveMapError, match="only PMC"):
        parse_drive_map({**base, "write": {"motor": {"kind": "diag", "number": 403}}})


def test_unreadable_or_invalid_toml_names_the_file(tmp_path: Path) -> None:
    with pytest.raises(DriveMapError, match="cannot read"):
        load_drive_map(tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("protocol = ")
    with pytest.raises(DriveMapError, match=r"bad\.toml: not valid TOML"):
        load_drive_map(bad)


@pytest.mark.parametrize(("url", "expected"), [
    ("opcua://10.0.0.5:4840", ("opcua", "opc.tcp://10.0.0.5:4840")),
    ("opc.tcp://h:4840", ("opcua", "opc.tcp://h:4840")),
    ("S7://plc:102", ("s7", "s7://plc:102")),
    ("modbus://127.0.0.1:502", ("modbus", "modbus://127.0.0.1:502")),
    ("focas://cnc:8193", ("focas", "focas://cnc:8193")),
])
def test_drive_endpoints(url: str, expected: tuple[str, str]) -> None:
    assert drive_endpoint(url) == expected


@pytest.mark.parametrize("url", ["http://x:1", "modbus:/x", "plc:502", "s7://"])
def test_bad_drive_endpoints(url: str) -> None:
    with pytest.raises(ValueError):
        drive_endpoint(url)


def test_endpoint_and_map_must_agree() -> None:
    with pytest.raises(ValueError, match="drive map is for modbus"):
        open_drive_driver("s7://127.0.0.1:102", parse_drive_map(_MODBUS))


def test_columns_are_consistent() -> None:
    assert set(RECORD_FIELDS) - {"dz_um"} <= set(DRIVE_COLUMNS)
