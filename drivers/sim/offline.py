"""Run the plant offline, faster than real time, into a calibration record.

No server, no event loop: the plant is stepped `period_s` at a time through a
program and sampled after each step (plus once at t = 0), so a record of
duration D at period P has floor(D / P) + 1 rows. Row k holds the sensors
at t = k·P; its speed is the one held over the period ending there (row 0 is
the machine at rest before the program starts). A day at 1 s takes well
under a few seconds (one 6×6 update per second of machine time).
"""

from __future__ import annotations

import math
import os

import numpy as np

from drivers.sim.csvlog import RECORD_COLUMNS, write_record
from drivers.sim.plant import PlantParams, ThermalPlant
from drivers.sim.programs import Program

#: spawn key separating the probe-noise stream from the plant's own streams
_PROBE_STREAM = 7


def simulate(program: Program, *, seed: int = 0, period_s: float = 1.0,
             duration_s: float | None = None, params: PlantParams | None = None,
             probe_noise_um: float = 0.5) -> dict[str, np.ndarray]:
    """Sample the plant running `program`; columns as in `RECORD_COLUMNS`
    plus ``growth_um`` (the true growth, without probe noise)."""
    if not (period_s > 0.0 and math.isfinite(period_s)):
        raise ValueError(f"period_s must be a positive finite number, got {period_s!r}")
    if probe_noise_um < 0.0:
        raise ValueError("probe_noise_um must be >= 0")
    duration = program.duration_s if duration_s is None else duration_s
    n = math.floor(duration / period_s + 1e-9) + 1
    plant = ThermalPlant(seed=seed, params=program.plant_params(params))
    names = ("spindle_rpm", "bearing", "motor", "column", "table", "ambient", "power_kw",
             "growth_um")
    out: dict[str, np.ndarray] = {name: np.empty(n) for name in names}
    cols = [out[name] for name in names]
    load = program.load
    for k in range(n):
        if k:
            plant.step(period_s, program((k - 1) * period_s), load)
        s = plant.sensors()
        for col, name in zip(cols, names, strict=True):
            col[k] = s[name]
    out["time_s"] = np.arange(n) * period_s
    probe = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(_PROBE_STREAM,)))
    out["dz_um"] = out["growth_um"] + probe_noise_um * probe.standard_normal(n)
    return out


def record_program(path: str | os.PathLike[str], program: Program, *, seed: int = 0,
                   period_s: float = 1.0, duration_s: float | None = None,
                   params: PlantParams | None = None, probe_noise_um: float = 0.5) -> int:
    """Simulate and write a calibration record CSV; return the number of rows."""
    columns = simulate(program, seed=seed, period_s=period_s, duration_s=duration_s,
                       params=params, probe_noise_um=probe_noise_um)
    return write_record(path, {c: columns[c] for c in RECORD_COLUMNS})
