"""One compensation cycle through FocasDriver vs direct ctypes calls.

A cycle = read every standard channel (one D-area pmc_rdpmcrng + one
cnc_diagnoss) + write offset, heartbeat and status (one pmc_wrpmcrng). The
peer makes the same three calls by hand through ctypes on the same stand-in
library and simulated CNC in the same run.

    .venv/bin/python benchmarks/bench_driver_focas.py [cycles]
"""

from __future__ import annotations

import asyncio
import ctypes
import statistics
import struct
import sys
import time

from drivers import focas_abi as abi
from drivers.focas import FocasDriver
from drivers.sim.focas_server import CHANNELS, OUTPUTS, FocasSimController


def _stats(samples_s: list[float]) -> tuple[float, float]:
    ordered = sorted(samples_s)
    return statistics.median(ordered) * 1e3, ordered[int(0.99 * (len(ordered) - 1))] * 1e3


def _bare(lib: ctypes.CDLL, sim: FocasSimController, cycles: int) -> list[float]:
    h = ctypes.c_uint16()
    if lib.cnc_allclibhndl3(sim.host.encode(), sim.port, 1, ctypes.byref(h)) != 0:
        raise RuntimeError("cnc_allclibhndl3 failed")
    rd = abi.pmc_buffer(24)
    wr = abi.pmc_buffer(10)
    dgn = abi.ODBDGN()
    hdr = abi.IODBPMC.from_buffer(wr)
    out: list[float] = []
    try:
        for i in range(cycles):
            t0 = time.perf_counter()
            lib.pmc_rdpmcrng(h.value, 9, 0, 0, 23, 32, rd)
            struct.unpack_from("<hhhhifff", bytes(rd[8:32]))
            lib.cnc_diagnoss(h.value, 403, 0, 8, ctypes.byref(dgn))
            hdr.type_a, hdr.type_d, hdr.datano_s, hdr.datano_e = 9, 0, 100, 109
            ctypes.memmove(ctypes.addressof(wr) + 8, struct.pack("<iih", 15 + i, i, 1), 10)
            lib.pmc_wrpmcrng(h.value, 18, wr)
            out.append(time.perf_counter() - t0)
    finally:
        lib.cnc_freelibhndl(h.value)
    return out


async def main(cycles: int) -> None:
    sim = FocasSimController()
    await sim.start()
    try:
        drv = FocasDriver(sim.endpoint, CHANNELS, OUTPUTS, library_path=sim.library_path)
        names = list(CHANNELS)
        ours: list[float] = []
        for i in range(cycles):
            t0 = time.perf_counter()
            await drv.read(names)
            await drv.write({"offset": 1.5 + i * 0.1, "heartbeat": i, "status": 1})
            ours.append(time.perf_counter() - t0)
        await drv.close()
        bare = _bare(abi.load(sim.library_path), sim, cycles)
    finally:
        await sim.stop()
        sim.close()
    (om, op), (bm, bp) = _stats(ours), _stats(bare)
    print(f"FOCAS cycle over {cycles} cycles (read 9 channels + write 3 outputs)")
    print(f"  FocasDriver (asyncio + worker thread): median {om:.4f} ms  p99 {op:.4f} ms")
    print(f"  ctypes direct calls, same library:     median {bm:.4f} ms  p99 {bp:.4f} ms")
    print(f"  overhead ratio: median {om / bm:.1f}x  p99 {op / bp:.1f}x")


if __name__ == "__main__":
    asyncio.run(main(int(sys.argv[1]) if len(sys.argv) > 1 else 2000))
