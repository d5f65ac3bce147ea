"""Interoperability with other Modbus implementations, on 127.0.0.1:

(a) `ModbusDriver` against a small server built on libmodbus (C, compiled
    with gcc at test time from tests/drivers/c/modbus_tcp_server.c);
(b) the simulated controller against Debian's `mbpoll` client.

Skipped (with the reason) only when gcc/libmodbus-dev or mbpoll is missing:
`apt-get install -y gcc libmodbus-dev mbpoll`.
"""

from __future__ import annotations

import asyncio
import re
import shutil
import struct
import subprocess
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from drivers.addresses import ModbusAddress
from drivers.backoff import Backoff
from drivers.errors import BadAddress
from drivers.modbus import ModbusDriver
from drivers.sim.modbus_server import ModbusSimController

C_SERVER = Path(__file__).parent / "c" / "modbus_tcp_server.c"
LIBMODBUS_HEADER = Path("/usr/include/modbus/modbus.h")
STEP_S = 10.0  # bound on any single subprocess step (never a timing assertion)


@pytest.fixture(scope="module")
def libmodbus_server(tmp_path_factory: pytest.TempPathFactory) -> Path:
    gcc = shutil.which("gcc")
    if gcc is None or not LIBMODBUS_HEADER.exists():
        pytest.skip("needs gcc and libmodbus-dev (apt-get install -y gcc libmodbus-dev)")
    binary = tmp_path_factory.mktemp("libmodbus") / "modbus_tcp_server"
    subprocess.run([gcc, "-Wall", "-Wextra", "-Werror", "-O1", "-I/usr/include/modbus",
                    "-o", str(binary), str(C_SERVER), "-lmodbus"],
                   check=True, capture_output=True, timeout=60)
    return binary


@pytest.fixture
async def c_server(libmodbus_server: Path) -> AsyncIterator[tuple[asyncio.subprocess.Process, int]]:
    proc = await asyncio.create_subprocess_exec(
        str(libmodbus_server), "0", stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE)
    try:
        assert proc.stdout is not None
        line = (await asyncio.wait_for(proc.stdout.readline(), STEP_S)).decode()
        match = re.fullmatch(r"LISTENING (\d+)\s*", line)
        assert match, f"libmodbus server said {line!r}"
        yield proc, int(match.group(1))
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()


C_CHANNELS = {
    "f_big": ModbusAddress(kind="input", address=0, type="float32"),
    "f_little": ModbusAddress(kind="input", address=2, type="float32", word_order="little"),
    "i16": ModbusAddress(kind="input", address=4, type="int16"),
    "sentinel": ModbusAddress(kind="input", address=5, type="int16", scale=0.1),
    "i32_milli": ModbusAddress(kind="input", address=6, type="int32", scale=0.001),
    "bogus": ModbusAddress(kind="input", address=100, type="int16"),
}
C_OUTPUTS = {
    "offset": ModbusAddress(kind="holding", address=0, type="float32"),
    "heartbeat": ModbusAddress(kind="holding", address=2, type="uint16"),
    "status": ModbusAddress(kind="holding", address=3, type="uint16"),
    "little": ModbusAddress(kind="holding", address=4, type="float32", word_order="little"),
    "neg_centi": ModbusAddress(kind="holding", address=6, type="int16", scale=0.01),
}


async def test_driver_against_libmodbus_server(
        c_server: tuple[asyncio.subprocess.Process, int]) -> None:
    proc, port = c_server
    driver = ModbusDriver(f"modbus://127.0.0.1:{port}", C_CHANNELS, C_OUTPUTS,
                          timeout_s=1.0, backoff=Backoff(0.05, 0.5))
    try:
        samples = await driver.read(["f_big", "f_little", "i16", "sentinel", "i32_milli"])
        with pytest.raises(BadAddress) as caught:  # libmodbus's own exception 2
            await driver.read(["bogus"])
        await driver.write({"offset": -12.5, "heartbeat": 65535, "status": 6,
                            "little": 3.75, "neg_centi": -1.23})
        back = await driver.read(list(C_OUTPUTS))
    finally:
        await driver.close()
    out, _ = await asyncio.wait_for(proc.communicate(), STEP_S)
    assert proc.returncode == 0

    assert samples["f_big"].value == 21.5
    assert samples["f_little"].value == -123.25
    assert samples["i16"].value == -1234
    assert samples["sentinel"].value == pytest.approx(3276.7)
    assert samples["i32_milli"].value == pytest.approx(-123.456)
    assert caught.value.channels == ("bogus",)
    assert "unit1/input/100:int16" in str(caught.value)
    assert back["offset"].value == -12.5
    assert back["heartbeat"].value == 65535
    assert back["little"].value == 3.75
    assert back["neg_centi"].value == pytest.approx(-1.23)

    # what libmodbus holds, word for word, as it printed on exit
    holding = {int(a): int(v) for a, v in re.findall(r"^HR (\d+) (\d+)$", out.decode(), re.M)}
    assert [holding[i] for i in range(8)] == [
        *struct.unpack(">HH", struct.pack(">f", -12.5)),   # big word order
        65535, 6,
        *reversed(struct.unpack(">HH", struct.pack(">f", 3.75))),  # little word order
        (-123) & 0xFFFF, 0,
    ]


# -- (b) the simulated controller under mbpoll ---------------------------------

@pytest.fixture
async def sim() -> AsyncIterator[ModbusSimController]:
    if shutil.which("mbpoll") is None:
        pytest.skip("needs Debian's mbpoll (apt-get install -y mbpoll)")
    controller = ModbusSimController()
    await controller.start()
    try:
        yield controller
    finally:
        await controller.stop()


async def mbpoll(sim: ModbusSimController, *args: str, values: tuple[str, ...] = ()) -> str:
    """Run mbpoll once against the sim (0-based references) and return its output.
    Async: the sim answers from this same event loop."""
    cmd = ["mbpoll", "-m", "tcp", "-a", "1", "-0", "-1", "-o", "2", *args,
           "127.0.0.1", "-p", str(sim.port)]
    if values:
        cmd += ["--", *values]
    proc = await asyncio.create_subprocess_exec(
        *cmd, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE)
    out, err = await asyncio.wait_for(proc.communicate(), STEP_S)
    assert proc.returncode == 0, (cmd, out.decode(), err.decode())
    return out.decode()


def polled(output: str) -> dict[int, str]:
    """{reference: value text} from mbpoll's "[ref]: value" lines (signed form
    when mbpoll prints one in parentheses)."""
    values: dict[int, str] = {}
    for ref, text, signed in re.findall(r"^\[(\d+)\]:\s+(\S+)(?: \((\S+)\))?", output, re.M):
        values[int(ref)] = signed or text
    return values


async def test_mbpoll_reads_sim_input_registers(sim: ModbusSimController) -> None:
    await sim.publish({"bearing": 31.2, "motor": 45.6, "column": 22.3, "table": -4.1,
                       "ambient": 20.5, "spindle_rpm": 12000, "power_kw": 7.5,
                       "growth_um": 12.25, "error_um": -3.5})
    words = polled(await mbpoll(sim, "-t", "3", "-r", "0", "-c", "6"))
    assert words == {0: "312", 1: "456", 2: "223", 3: "-41", 4: "205", 5: "12000"}
    floats = polled(await mbpoll(sim, "-t", "3:float", "-B", "-r", "6", "-c", "3"))
    assert {k: float(v) for k, v in floats.items()} == {6: 7.5, 8: 12.25, 10: -3.5}
    assert [(r.function_code, r.address, r.count) for r in sim.requests] == [
        (4, 0, 6), (4, 6, 6)]


async def test_mbpoll_writes_sim_holding_registers(sim: ModbusSimController) -> None:
    await mbpoll(sim, "-t", "4:float", "-B", "-r", "0", values=("-12.5",))
    await mbpoll(sim, "-t", "4", "-r", "2", values=("7", "3"))
    # without -B mbpoll puts the low word first: the sim's little-word-order float
    await mbpoll(sim, "-t", "4:float", "-r", "10", values=("-2.5",))
    # mbpoll writes 16-bit registers as unsigned only: -300 as its two's complement
    await mbpoll(sim, "-t", "4", "-r", "14", values=(str(-300 & 0xFFFF),))
    assert await sim.outputs() == {"offset": -12.5, "heartbeat": 7, "status": 3}
    values = await sim.read_values(["enc_f32_little", "enc_i16"])
    assert values == {"enc_f32_little": -2.5, "enc_i16": -300}
    # and mbpoll reads back what it wrote
    back = polled(await mbpoll(sim, "-t", "4:float", "-B", "-r", "0", "-c", "1"))
    assert float(back[0]) == -12.5
