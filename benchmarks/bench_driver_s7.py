"""One compensation cycle through S7Driver vs the bare snap7 client.

A cycle = read every standard channel (one DB) + write offset, heartbeat and
status (one adjacent run). The peer does the same two requests by hand with
snap7.client.Client in the same run against the same server.

    .venv/bin/python benchmarks/bench_driver_s7.py [cycles]
"""

from __future__ import annotations

import asyncio
import statistics
import struct
import sys
import time

from snap7.client import Client

from drivers.s7 import S7Driver
from drivers.sim.s7_server import CHANNELS, OUTPUTS, S7SimController


def _stats(samples_s: list[float]) -> tuple[float, float]:
    ordered = sorted(samples_s)
    return statistics.median(ordered) * 1e3, ordered[int(0.99 * (len(ordered) - 1))] * 1e3


async def main(cycles: int) -> None:
    sim = S7SimController()
    await sim.start()
    try:
        await sim.publish({"bearing": 24.5, "speed_rpm": 9000, "power_kw": 3.0})
        drv = S7Driver(sim.endpoint, CHANNELS, OUTPUTS, timeout_s=0.5)
        names = list(CHANNELS)
        ours: list[float] = []
        for i in range(cycles):
            t0 = time.perf_counter()
            await drv.read(names)
            await drv.write({"offset": 1.5 + i * 1e-3, "heartbeat": i, "status": 1})
            ours.append(time.perf_counter() - t0)
        await drv.close()

        client = Client()
        client.connect(sim.host, 0, 1, sim.port)
        bare: list[float] = []
        for i in range(cycles):
            t0 = time.perf_counter()
            data = client.db_read(1, 0, 26)
            struct.unpack_from(">hhhhhiff", data, 0)
            struct.unpack_from(">f", data, 22)
            client.db_write(2, 0, bytearray(struct.pack(">fiH", 1.5 + i * 1e-3, i, 1)))
            bare.append(time.perf_counter() - t0)
        client.disconnect()
    finally:
        await sim.stop()
    (om, op), (bm, bp) = _stats(ours), _stats(bare)
    print(f"S7 cycle over {cycles} cycles (read 9 channels + write 3 outputs)")
    print(f"  S7Driver (asyncio + worker thread): median {om:.3f} ms  p99 {op:.3f} ms")
    print(f"  snap7 Client, direct calls:         median {bm:.3f} ms  p99 {bp:.3f} ms")
    print(f"  overhead ratio: median {om / bm:.2f}x  p99 {op / bp:.2f}x")


if __name__ == "__main__":
    asyncio.run(main(int(sys.argv[1]) if len(sys.argv) > 1 else 2000))
