"""FOCAS driver against the stand-in libfwlib32 (compiled with gcc here)."""

from __future__ import annotations

import asyncio
import ctypes
import subprocess
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from drivers import focas_abi as abi
from drivers.addresses import FocasPmcAddress
from drivers.backoff import Backoff
from drivers.errors import BadAddress, ConnectionLost, ControllerTimeout, DriverError, WriteRejected
from drivers.focas import FocasDriver, LibraryRefusedError, sha256_file
from drivers.sim.focas_server import (
    CHANNELS,
    ENCODINGS,
    EXTRAS,
    OUTPUTS,
    SHM_BYTES,
    FocasSimController,
)
from drivers.sim.fwlib_build import build_abi_probe


@pytest.fixture
async def sim(tmp_path_factory: pytest.TempPathFactory) -> AsyncIterator[FocasSimController]:
    lib_dir = tmp_path_factory.getbasetemp() / "fwlib"
    controller = FocasSimController(library_dir=str(lib_dir))
    await controller.start()
    try:
        yield controller
    finally:
        await controller.stop()
        controller.close()


def _driver(sim: FocasSimController, timeout_s: float = 0.5, **kw: object) -> FocasDriver:
    kw.setdefault("library_path", sim.library_path)
    kw.setdefault("backoff", Backoff(0.01, 0.05))
    return FocasDriver(sim.endpoint, {**CHANNELS, **EXTRAS, **ENCODINGS},
                       {**OUTPUTS, **ENCODINGS}, timeout_s=timeout_s,
                       **kw)  # type: ignore[arg-type]


def test_ctypes_layouts_match_the_c_compiler(tmp_path: Path) -> None:
    out = subprocess.run([str(build_abi_probe(tmp_path))], check=True, capture_output=True,
                         text=True).stdout
    c = {line.split()[0]: [int(x) for x in line.split()[1:]] for line in out.splitlines()}
    assert c["IODBPMC"] == [ctypes.sizeof(abi.IODBPMC), abi.IODBPMC.type_d.offset,
                            abi.IODBPMC.datano_s.offset, abi.IODBPMC.datano_e.offset,
                            abi.IODBPMC.u.offset]
    assert c["ODBSPN"] == [ctypes.sizeof(abi.ODBSPN), abi.ODBSPN.type.offset,
                           abi.ODBSPN.data.offset]
    assert c["ODBDGN"] == [ctypes.sizeof(abi.ODBDGN), abi.ODBDGN.type.offset,
                           abi.ODBDGN.u.offset]
    assert c["REALDGN"] == [ctypes.sizeof(abi.REALDGN), abi.REALDGN.dec_val.offset]
    assert c["SHM"][0] == SHM_BYTES  # the simulator's view of the shared memory
    assert abi.IODBPMC.u.offset == abi.PMC_HEADER_BYTES


def test_return_code_mapping() -> None:
    for code in (abi.EW_SOCKET, abi.EW_HANDLE):
        assert type(abi.error_for(code, "x", writing=True)) is ConnectionLost
    for code in (abi.EW_NUMBER, abi.EW_ATTRIB, abi.EW_LENGTH):
        err = abi.error_for(code, "pmc_rdpmcrng", channel="c", address="PMC D0:long")
        assert type(err) is BadAddress and err.channels == ("c",) and err.address == "PMC D0:long"
    for code in (abi.EW_BUSY, abi.EW_RESET):
        werr = abi.error_for(code, "pmc_wrpmcrng", writing=True)
        assert isinstance(werr, WriteRejected) and not werr.permanent
    for code in (abi.EW_PROT, abi.EW_REJECT, abi.EW_PASSWD):
        werr = abi.error_for(code, "pmc_wrpmcrng", writing=True)
        assert isinstance(werr, WriteRejected) and werr.permanent
    assert "EW_BUSY" in str(abi.error_for(abi.EW_BUSY, "pmc_rdpmcrng"))
    assert type(abi.error_for(abi.EW_BUSY, "pmc_rdpmcrng")) is DriverError


async def test_reads_one_call_per_area_and_source(sim: FocasSimController) -> None:
    await sim.publish({"bearing": 3276.7, "motor": 61.4, "table": -12.5, "spindle_rpm": 8000,
                       "power_kw": 3.5, "servo_z_temp": 44.0, "spindle_load_pct": 37,
                       "enc_r_long": -5})
    drv = _driver(sim)
    try:
        await drv.connect()
        before = sim.calls
        got = await drv.read([*CHANNELS, *EXTRAS, "enc_r_long"])
        # one D-area range, one R-area range, one cnc_rdspload, two cnc_diagnoss
        assert sim.calls - before == 5
        assert got["bearing"].value == pytest.approx(3276.7)  # Pt100 open: raw 32767 passes
        assert got["motor"].value == pytest.approx(61.4)
        assert got["table"].value == pytest.approx(-12.5)
        assert got["spindle_rpm"].value == 8000 and got["power_kw"].value == 3.5
        assert got["servo_z_temp"].value == pytest.approx(44.0)
        assert got["spindle_load_pct"].value == 37 and got["enc_r_long"].value == -5
        before = sim.calls
        await drv.write({"offset": -12.3, "heartbeat": 9, "status": 2})
        assert sim.calls - before == 1  # {offset, heartbeat, status} in one request
        assert await sim.outputs() == pytest.approx({"offset": -12.3, "heartbeat": 9,
                                                     "status": 2})
    finally:
        await drv.close()


async def test_pulled_cable_is_connection_lost_then_recovers(sim: FocasSimController) -> None:
    drv = _driver(sim)
    try:
        await drv.read(["bearing"])
        await sim.stop()
        with pytest.raises(ConnectionLost, match="EW_SOCKET"):
            await drv.read(["bearing"])
        with pytest.raises(ConnectionLost):
            await drv.read(["bearing"])
        assert not drv.connected
        await sim.start()
        await _until_read(drv)
    finally:
        await drv.close()


async def test_lost_link_fails_fast_while_backing_off(sim: FocasSimController) -> None:
    drv = _driver(sim, backoff=Backoff(30.0, 30.0))
    try:
        await drv.read(["bearing"])
        await sim.stop()
        with pytest.raises(ConnectionLost, match="EW_SOCKET"):
            await drv.read(["bearing"])
        # within the backoff delay the next call does not touch the library
        with pytest.raises(ConnectionLost, match="next reconnect attempt"):
            await drv.read(["bearing"])
    finally:
        await drv.close()
        await sim.start()


async def _until_read(drv: FocasDriver) -> None:
    for _ in range(100):
        try:
            await drv.read(["bearing"])
            return
        except ConnectionLost:
            await asyncio.sleep(0.01)
    pytest.fail("driver did not reconnect")


async def test_power_cycle_makes_the_handle_stale(sim: FocasSimController) -> None:
    drv = _driver(sim)
    try:
        await drv.write({"offset": 10.0})
        await sim.stop()
        await sim.forget_outputs()
        await sim.start()  # generation bumped: the old handle is stale
        with pytest.raises(ConnectionLost, match="EW_HANDLE"):
            await drv.read(["offset"])
        await _until_read(drv)
        assert (await drv.read(["offset"]))["offset"].value == 0.0
    finally:
        await drv.close()


async def test_latency_beyond_timeout_is_a_timeout_not_a_hang(sim: FocasSimController) -> None:
    drv = _driver(sim, timeout_s=0.05)
    try:
        await drv.read(["bearing"])
        sim.set_latency_us(600_000)
        with pytest.raises(ControllerTimeout):
            await drv.read(["bearing"])
        sim.set_latency_us(0)
        await asyncio.sleep(0.7)  # the abandoned call finishes on the worker thread
        await _until_read(drv)
    finally:
        await drv.close()


async def test_refusals_name_channel_and_address(sim: FocasSimController) -> None:
    f_area = FocasPmcAddress(area="F", address=0, type="word")
    far = FocasPmcAddress(area="D", address=8190, type="double")
    drv = FocasDriver(sim.endpoint, {"far": far, **CHANNELS}, {"f_word": f_area, **OUTPUTS},
                      library_path=sim.library_path)
    try:
        with pytest.raises(BadAddress) as info:
            await drv.read(["bearing", "far"])
        assert (info.value.channels, info.value.address) == (("far",), "PMC D8190:double")
        with pytest.raises(WriteRejected) as winfo:
            await drv.write({"f_word": 1})
        assert winfo.value.permanent and winfo.value.channels == ("f_word",)
        with pytest.raises(BadAddress) as einfo:
            await drv.write({"status": 40000})  # a PMC word is signed 16 bit
        assert einfo.value.channels == ("status",)
    finally:
        await drv.close()


async def test_all_library_calls_on_one_thread(sim: FocasSimController) -> None:
    drv = _driver(sim)
    try:
        for _ in range(5):
            await asyncio.gather(drv.read(["bearing", "motor"]), drv.write({"heartbeat": 1}))
        assert len(drv.io_thread.thread_ids) == 1
    finally:
        await drv.close()


def test_library_path_must_be_absolute_and_pinned(sim: FocasSimController) -> None:
    with pytest.raises(LibraryRefusedError, match="absolute"):
        FocasDriver(sim.endpoint, CHANNELS, OUTPUTS, library_path="libfwlib32.so")
    with pytest.raises(LibraryRefusedError, match="sha256"):
        FocasDriver(sim.endpoint, CHANNELS, OUTPUTS,
                    library_path=sim.library_path, library_sha256="0" * 64)
    FocasDriver(sim.endpoint, CHANNELS, OUTPUTS,
                library_path=sim.library_path, library_sha256=sha256_file(sim.library_path))
