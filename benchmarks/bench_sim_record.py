"""How much faster than real time the simulated plant writes a calibration record.

Peer: the machine time it simulates (a real test run of the same program takes
exactly that long), so the figure is a ratio, not a bare time. Also prints the
cost of the per-step exact-exponential update against the sensor sampling in
the same run.

    .venv/bin/python benchmarks/bench_sim_record.py [hours]
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

from drivers.sim.offline import record_program, simulate
from drivers.sim.plant import ThermalPlant
from drivers.sim.programs import make_program


def main() -> None:
    hours = float(sys.argv[1]) if len(sys.argv) > 1 else 24.0
    program = make_program("spectrum", seed=1, hours=hours)
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        rows = record_program(Path(tmp) / "rec.csv", program, seed=1)
        wall_s = time.perf_counter() - t0
    print(f"record: {rows} rows of 1 s ({hours:g} h machine time): "
          f"{program.duration_s / wall_s:,.0f}x faster than real time")

    t0 = time.perf_counter()
    simulate(program, seed=1)
    sim_s = time.perf_counter() - t0
    plant = ThermalPlant(seed=1)
    n = int(program.duration_s)
    t0 = time.perf_counter()
    for k in range(n):
        plant.step(1.0, program(float(k)))
    step_s = time.perf_counter() - t0
    print(f"of which stepping only: {step_s / sim_s:.0%} of simulate(); "
          f"CSV formatting and writing: {(wall_s - sim_s) / wall_s:.0%} of the record")


if __name__ == "__main__":
    main()
