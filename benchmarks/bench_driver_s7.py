"""One compensation cycle through S7Driver vs two peers, in the same run.

A cycle = read every standard channel (one DB) + write offset, heartbeat and
status (one adjacent run), against the simulated CPU on loopback. Peers, on
their own connections to the same server:

- ``bare``: snap7.client.Client called directly, synchronously (the issue's
  ratio, target under 1.2x). It blocks its caller for the whole cycle, which
  a daemon on an event loop may not do.
- ``hop``: the same bare calls made from asyncio through the thinnest
  standard thread hop: ``loop.run_in_executor`` on a dedicated single-thread
  executor, one hop for the read and one for the write (a driver's read and
  write are separate awaits). No timeouts, no error mapping, no reconnect:
  the floor any non-blocking use of a blocking library pays.

The three are measured in interleaved blocks of cycles (driver, bare, hop,
driver, ...), so that load from other processes on the machine lands on all
of them alike. Absolute figures depend on where the scheduler puts the
client, worker and (in-process) server threads: on this 2-vCPU VM a wakeup
across vCPUs costs tens of µs, so ``taskset -c 0`` gives lower, steadier
figures for every peer; compare ratios, not runs.

    .venv/bin/python benchmarks/bench_driver_s7.py [cycles]
"""

from __future__ import annotations

import asyncio
import statistics
import struct
import sys
import time
from collections.abc import Awaitable, Callable
from concurrent.futures import ThreadPoolExecutor

from snap7.client import Client

from drivers.s7 import S7Driver
from drivers.sim.s7_server import CHANNELS, OUTPUTS, S7SimController

_BLOCK = 100


def _stats(samples_s: list[float]) -> tuple[float, float]:
    ordered = sorted(samples_s)
    return statistics.median(ordered) * 1e3, ordered[int(0.99 * (len(ordered) - 1))] * 1e3


async def _measure(peers: dict[str, Callable[[int], Awaitable[None]]],
                   cycles: int) -> dict[str, list[float]]:
    times: dict[str, list[float]] = {name: [] for name in peers}
    for cycle in peers.values():  # warm-up: connections, plans, caches
        for i in range(20):
            await cycle(i)
    done = 0
    while done < cycles:
        n = min(_BLOCK, cycles - done)
        for name, cycle in peers.items():
            out = times[name]
            for i in range(done, done + n):
                t0 = time.perf_counter()
                await cycle(i)
                out.append(time.perf_counter() - t0)
        done += n
    return times


async def main(cycles: int) -> None:
    sim = S7SimController()
    await sim.start()
    drv = S7Driver(sim.endpoint, CHANNELS, OUTPUTS, timeout_s=0.5)
    bare_client, hop_client = Client(), Client()
    executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="bench-hop")
    try:
        await sim.publish({"bearing": 24.5, "spindle_rpm": 9000, "power_kw": 3.0})
        names = list(CHANNELS)
        bare_client.connect(sim.host, 0, 1, sim.port)
        hop_client.connect(sim.host, 0, 1, sim.port)
        loop = asyncio.get_running_loop()

        def read_by_hand(client: Client) -> None:
            data = client.db_read(1, 0, 26)
            struct.unpack_from(">hhhhhiff", data, 0)
            struct.unpack_from(">f", data, 22)

        def write_by_hand(client: Client, i: int) -> None:
            client.db_write(2, 0, bytearray(struct.pack(">fiH", 1.5 + i * 1e-3, i, 1)))

        async def driver(i: int) -> None:
            await drv.read(names)
            await drv.write({"offset": 1.5 + i * 1e-3, "heartbeat": i, "status": 1})

        async def bare(i: int) -> None:
            read_by_hand(bare_client)
            write_by_hand(bare_client, i)

        async def hop(i: int) -> None:
            await loop.run_in_executor(executor, read_by_hand, hop_client)
            await loop.run_in_executor(executor, write_by_hand, hop_client, i)

        times = await _measure({"driver": driver, "bare": bare, "hop": hop}, cycles)
    finally:
        await drv.close()
        bare_client.disconnect()
        hop_client.disconnect()
        executor.shutdown()
        await sim.stop()
    (dm, dp), (bm, bp), (hm, hp) = (_stats(times[k]) for k in ("driver", "bare", "hop"))
    print(f"S7 cycle over {cycles} cycles (read 9 channels + write 3 outputs), "
          f"interleaved blocks of {_BLOCK}")
    print(f"  driver  S7Driver (asyncio + worker thread):   median {dm:.3f} ms  p99 {dp:.3f} ms")
    print(f"  bare    snap7 Client, direct sync calls:      median {bm:.3f} ms  p99 {bp:.3f} ms")
    print(f"  hop     snap7 Client via run_in_executor x2:  median {hm:.3f} ms  p99 {hp:.3f} ms")
    print(f"  driver / bare: median {dm / bm:.2f}x  p99 {dp / bp:.2f}x  (issue target < 1.2x: "
          f"{'met' if dm / bm < 1.2 else 'NOT met'})")
    print(f"  driver / hop:  median {dm / hm:.2f}x  p99 {dp / hp:.2f}x")
    print(f"  hop / bare:    median {hm / bm:.2f}x  p99 {hp / bp:.2f}x  (the thread-hop floor)")


if __name__ == "__main__":
    asyncio.run(main(int(sys.argv[1]) if len(sys.argv) > 1 else 2000))
