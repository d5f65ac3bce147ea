"""One compensation cycle over Modbus TCP on loopback: read all nine channels
and write the offset, against the simulated controller (pymodbus server).

Peer, measured in the same run against the same server: the bare pymodbus
async client doing the same two requests by hand (read 12 input registers,
decode them with struct, write the offset's 2 holding registers). The cycles
alternate in blocks so both see the same machine state.

The CPU per cycle (`time.process_time` over each block, the simulated
controller's share included, the same for both) is printed beside: what a
thousand machines in one process pay a second.

Run:  .venv/bin/python benchmarks/bench_driver_modbus.py [--cycles 2000]
Target: driver / bare median ratio < 1.2.
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import struct
import time
from collections.abc import Awaitable, Callable

from pymodbus.client import AsyncModbusTcpClient

from drivers.backoff import Backoff
from drivers.modbus import ModbusDriver
from drivers.sim import CHANNELS
from drivers.sim.modbus_server import ModbusSimController

BLOCK = 100


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, round(q * (len(ordered) - 1)))]


async def main(cycles: int) -> None:
    sim = ModbusSimController()
    await sim.start()
    await sim.publish({"bearing": 31.2, "motor": 45.6, "column": 22.3, "table": 24.1,
                       "ambient": 20.5, "spindle_rpm": 12000, "power_kw": 7.5,
                       "growth_um": 12.25, "error_um": -3.5})
    driver = ModbusDriver(sim.endpoint, sim.channels, sim.outputs_map, timeout_s=0.5,
                          backoff=Backoff(0.05, 1.0))
    bare = AsyncModbusTcpClient("127.0.0.1", port=sim.port, timeout=0.5, retries=0,
                                reconnect_delay=0)
    names = list(CHANNELS)
    offset = [0.0]

    async def driver_cycle() -> None:
        await driver.read(names)
        offset[0] += 0.25
        await driver.write({"offset": offset[0]})

    async def bare_cycle() -> None:
        rr = await bare.read_input_registers(0, count=12, device_id=1)
        if rr.isError():
            raise RuntimeError(rr)
        regs = rr.registers
        temps = [(r - 0x10000 if r & 0x8000 else r) * 0.1 for r in regs[0:5]]
        floats = struct.unpack(">fff", struct.pack(">6H", *regs[6:12]))
        values = {*temps, float(regs[5]), *floats}
        if not values:
            raise RuntimeError("no values")
        offset[0] += 0.25
        words = list(struct.unpack(">HH", struct.pack(">f", offset[0])))
        wr = await bare.write_registers(0, words, device_id=1)
        if wr.isError():
            raise RuntimeError(wr)

    async def run(cycle: Callable[[], Awaitable[None]], n: int, out: list[float]) -> None:
        for _ in range(n):
            t0 = time.perf_counter_ns()
            await cycle()
            out.append((time.perf_counter_ns() - t0) / 1e6)

    try:
        await driver.connect()
        if not await bare.connect():
            raise RuntimeError("bare client could not connect")
        warm: list[float] = []
        await run(driver_cycle, 200, warm)
        await run(bare_cycle, 200, warm)
        d_ms: list[float] = []
        b_ms: list[float] = []
        cpu = {"driver": 0.0, "bare": 0.0}
        for _ in range(0, cycles, BLOCK):
            for key, cycle, out in (("driver", driver_cycle, d_ms), ("bare", bare_cycle, b_ms)):
                c0 = time.process_time()
                await run(cycle, BLOCK, out)
                cpu[key] += time.process_time() - c0
    finally:
        await driver.close()
        bare.close()
        await sim.stop()

    d_med, b_med = statistics.median(d_ms), statistics.median(b_ms)
    d_p99, b_p99 = percentile(d_ms, 0.99), percentile(b_ms, 0.99)
    print(f"Modbus TCP cycle (read 9 channels + write offset), loopback, "
          f"{len(d_ms)} cycles each")
    print(f"  {'':28s}{'median ms':>12s}{'p90 ms':>10s}{'p99 ms':>10s}")
    print(f"  {'ModbusDriver':28s}{d_med:12.3f}{percentile(d_ms, 0.9):10.3f}{d_p99:10.3f}")
    print(f"  {'bare pymodbus async client':28s}{b_med:12.3f}{percentile(b_ms, 0.9):10.3f}"
          f"{b_p99:10.3f}")
    print(f"  overhead ratio (driver / bare): median {d_med / b_med:.2f}x, "
          f"p99 {d_p99 / b_p99:.2f}x  (target median < 1.2x)")
    d_cpu, b_cpu = cpu["driver"] / len(d_ms) * 1e6, cpu["bare"] / len(b_ms) * 1e6
    print(f"  CPU per cycle (this process, simulated controller included): driver "
          f"{d_cpu:.0f} us, bare {b_cpu:.0f} us, ratio {d_cpu / b_cpu:.2f}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=2000)
    asyncio.run(main(parser.parse_args().cycles))
