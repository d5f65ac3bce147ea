"""OPC UA driver overhead: one full cycle (read every standard channel in one
Read + write the offset) against the simulated server on loopback, through
`OpcUaDriver` and through the bare asyncua client doing the same two requests
by hand (prebuilt ReadParameters, a Float Variant), in the same run.

    .venv/bin/python benchmarks/bench_driver_opcua.py [--cycles 2000]

Prints median and p99 per cycle for both and the overhead ratio (target < 1.2x).
"""

from __future__ import annotations

import argparse
import asyncio
import gc
import logging
import statistics
import time
from collections.abc import Awaitable, Callable

from asyncua import ua
from asyncua.client.client import Client
from asyncua.ua.attribute_ids import AttributeIds

from drivers.opcua import OpcUaDriver
from drivers.sim import CHANNELS
from drivers.sim.opcua_server import OpcUaSimController


async def _measure(cycle: Callable[[int], Awaitable[None]], cycles: int) -> list[float]:
    for i in range(100):  # warm up
        await cycle(i)
    times: list[float] = []
    for i in range(cycles):
        t0 = time.perf_counter()
        await cycle(i)
        times.append(time.perf_counter() - t0)
    return times


def _stats(times: list[float]) -> tuple[float, float]:
    ordered = sorted(times)
    return statistics.median(ordered) * 1e3, ordered[int(0.99 * (len(ordered) - 1))] * 1e3


async def main(cycles: int, rounds: int) -> None:
    logging.disable(logging.WARNING)
    sim = OpcUaSimController()
    await sim.start()
    names = list(CHANNELS)
    driver = OpcUaDriver(sim.endpoint, dict(sim.channels),  # type: ignore[arg-type]
                         dict(sim.outputs_map), timeout_s=0.5)  # type: ignore[arg-type]
    await driver.connect()
    client = Client(sim.endpoint, timeout=0.5)
    await client.connect()
    params = ua.ReadParameters()
    params.TimestampsToReturn = ua.TimestampsToReturn.Both
    for name in names:
        rv = ua.ReadValueId()
        rv.NodeId = ua.NodeId.from_string(sim.channels[name].describe())
        rv.AttributeId = AttributeIds.Value
        params.NodesToRead.append(rv)
    offset_node = ua.NodeId.from_string(sim.outputs_map["offset"].describe())
    # The in-process server's address space is ~100k objects: without this a
    # full GC pass lands in ~1 % of cycles (10+ ms) for both clients alike.
    gc.collect()
    gc.freeze()

    async def driver_cycle(i: int) -> None:
        await driver.read(names)
        await driver.write({"offset": i * 0.5})

    async def bare_cycle(i: int) -> None:
        results = await client.uaclient.read(params)
        _ = [float(dv.Value.Value) for dv in results]
        wp = ua.WriteParameters()
        wv = ua.WriteValue()
        wv.NodeId = offset_node
        wv.AttributeId = AttributeIds.Value
        wv.Value = ua.DataValue(ua.Variant(i * 0.5, ua.VariantType.Float))
        wp.NodesToWrite.append(wv)
        (await client.uaclient.write(wp))[0].check()

    try:
        drv: list[float] = []
        bare: list[float] = []
        # interleave rounds so drift on a shared machine hits both alike
        for _ in range(rounds):
            drv += await _measure(driver_cycle, cycles // rounds)
            bare += await _measure(bare_cycle, cycles // rounds)
    finally:
        await driver.close()
        await client.disconnect()
        await sim.stop()
    d_med, d_p99 = _stats(drv)
    b_med, b_p99 = _stats(bare)
    print(f"OPC UA full cycle (read {len(names)} channels in one Read + write offset), "
          f"{len(drv)} cycles each, loopback, sim server in the same process")
    print(f"  OpcUaDriver     median {d_med:.3f} ms  p99 {d_p99:.3f} ms")
    print(f"  bare asyncua    median {b_med:.3f} ms  p99 {b_p99:.3f} ms")
    print(f"  overhead ratio  median {d_med / b_med:.2f}x  p99 {d_p99 / b_p99:.2f}x "
          "(target < 1.2x)")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=2000)
    parser.add_argument("--rounds", type=int, default=4)
    args = parser.parse_args()
    asyncio.run(main(args.cycles, args.rounds))
