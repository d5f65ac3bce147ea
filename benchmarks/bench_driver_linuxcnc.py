"""One compensation cycle through the LinuxCNC driver against a real headless
LinuxCNC: read the channels, the offset read-back and the machine's state,
write the offset (a changed count each cycle: LinuxCNC's servo thread takes it
before the write returns), the heartbeat and the status word.

Peer, measured in the same run: the Modbus driver doing the same cycle
(channels + read-back, offset + heartbeat + status) against the simulated
Modbus controller on loopback. Cycles alternate in blocks so both see the same
machine load. Prints medians, p90, p99 and the ratio LinuxCNC / Modbus.

Run:  .venv/bin/python benchmarks/bench_driver_linuxcnc.py [--cycles 2000]
(needs linuxcnc-uspace; takes the one-LinuxCNC-per-machine lock)
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import time
from collections.abc import Awaitable, Callable

from drivers.backoff import Backoff
from drivers.base import Driver
from drivers.linuxcnc import LinuxCncDriver
from drivers.modbus import ModbusDriver
from drivers.sim.linuxcnc_machine import (
    ForeignLinuxCnc,
    LinuxCncBusy,
    LinuxCncSimController,
    unavailable,
)
from drivers.sim.modbus_server import ModbusSimController

BLOCK = 100
CHANNELS = ("bearing", "motor", "column", "table", "ambient", "spindle_rpm")
VALUES = {"bearing": 31.2, "motor": 45.6, "column": 22.3, "table": 24.1, "ambient": 20.5}


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, round(q * (len(ordered) - 1)))]


def cycle_of(driver: Driver, reads: list[str], step_um: float) -> Callable[[], Awaitable[None]]:
    state = {"offset": 0.0, "heartbeat": 0}

    async def cycle() -> None:
        await driver.read(reads)
        state["offset"] = (state["offset"] + step_um) % 50.0
        state["heartbeat"] = (state["heartbeat"] + 1) % 32768
        await driver.write({"offset": state["offset"], "heartbeat": state["heartbeat"],
                            "status": 1})

    return cycle


async def run(cycle: Callable[[], Awaitable[None]], n: int, out: list[float]) -> None:
    for _ in range(n):
        t0 = time.perf_counter_ns()
        await cycle()
        out.append((time.perf_counter_ns() - t0) / 1e6)


async def main(cycles: int) -> None:
    why = unavailable()
    if why is not None:
        raise SystemExit(f"bench_driver_linuxcnc: {why}")
    lcnc, mb = LinuxCncSimController(), ModbusSimController()
    try:
        await lcnc.start()
    except (ForeignLinuxCnc, LinuxCncBusy) as exc:
        raise SystemExit(f"bench_driver_linuxcnc: {exc}") from None
    await mb.start()
    await lcnc.publish(VALUES)
    await mb.publish({**VALUES, "spindle_rpm": 9000})
    lc_driver = LinuxCncDriver(lcnc.endpoint, {**lcnc.channels, **lcnc.states},
                               lcnc.outputs_map, timeout_s=1.0, connect_timeout_s=60.0,
                               component=lcnc.component)
    mb_driver = ModbusDriver(mb.endpoint, mb.channels, mb.outputs_map, timeout_s=0.5,
                             backoff=Backoff(0.05, 1.0))
    # 0.3 µm a cycle: three counts of 0.1 µm, so every LinuxCNC write is a change
    lc_cycle = cycle_of(lc_driver, [*CHANNELS, "offset", "machine_on", "estop"], 0.3)
    # the same offset every cycle: no count changes, no wait for the servo thread
    # (what the HAL side's pipe and pins cost alone)
    lc_hold = cycle_of(lc_driver, [*CHANNELS, "offset", "machine_on", "estop"], 0.0)
    mb_cycle = cycle_of(mb_driver, [*CHANNELS, "offset"], 0.3)
    try:
        await lc_driver.connect()
        await mb_driver.connect()
        warm: list[float] = []
        await run(lc_cycle, 200, warm)
        await run(mb_cycle, 200, warm)
        lc_ms: list[float] = []
        hold_ms: list[float] = []
        mb_ms: list[float] = []
        for _ in range(0, cycles, BLOCK):
            await run(lc_cycle, BLOCK, lc_ms)
            await run(lc_hold, BLOCK, hold_ms)
            await run(mb_cycle, BLOCK, mb_ms)
    finally:
        await lc_driver.close()
        await mb_driver.close()
        await mb.stop()
        await lcnc.stop()

    print(f"one cycle: read 6 channels + offset read-back (+ machine state for LinuxCNC), "
          f"write offset + heartbeat + status; {len(lc_ms)} cycles each")
    print(f"  {'':34s}{'median ms':>12s}{'p90 ms':>10s}{'p99 ms':>10s}")
    for name, ms in (("LinuxCncDriver, offset moving", lc_ms),
                     ("LinuxCncDriver, offset held", hold_ms),
                     ("ModbusDriver (TCP loopback, sim)", mb_ms)):
        print(f"  {name:34s}{statistics.median(ms):12.3f}{percentile(ms, 0.9):10.3f}"
              f"{percentile(ms, 0.99):10.3f}")
    for name, ms in (("moving", lc_ms), ("held", hold_ms)):
        print(f"  ratio LinuxCNC ({name}) / Modbus: median "
              f"{statistics.median(ms) / statistics.median(mb_ms):.2f}x, p99 "
              f"{percentile(ms, 0.99) / percentile(mb_ms, 0.99):.2f}x")
    print("  (a moving offset waits for LinuxCNC's 1 ms servo thread to take the new "
          "counts before the write returns)")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=2000)
    asyncio.run(main(parser.parse_args().cycles))
