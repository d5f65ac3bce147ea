"""A simulated machine: the thermal plant behind a simulated controller.

Each tick advances the plant by `period_s` of machine time at the program's
speed, reads what the daemon wrote (`controller.outputs()`) and applies the
``offset`` (µm) to the plant, then publishes `plant.sensors()` (so the
published ``error_um`` = growth - the offset in force at that instant) and,
if asked, records the row.

A measuring cycle (`probe_every_s` machine seconds, off by default) probes
the tool's Z as a touch probe on a reference would on a compensating
machine: ``probe_value`` = growth - the offset in force + Gaussian noise of
`probe_noise_um`, and ``probe_counter`` advanced by one (a new measurement).
`spoil_next_probe(um)` adds an error to the next measurement only (a chip
under the probe).

Scheduling (`tick`, `run`, `start`/`stop`) and the history come from
`drivers.sim.runner.PlantRunner`.
"""

from __future__ import annotations

import math

import numpy as np

from drivers.sim import CHANNELS
from drivers.sim.base import SimController
from drivers.sim.plant import ThermalPlant
from drivers.sim.programs import Program
from drivers.sim.runner import PlantRunner

#: columns of a recorded row (besides the standard channels)
HISTORY_COLUMNS: tuple[str, ...] = ("time_s", *CHANNELS, "offset_um")


class SimMachine(PlantRunner):
    """Couples a `ThermalPlant` to any `SimController`.

    The caller owns the controller's lifecycle (`start()`/`stop()` of the
    server); the machine only publishes to it and reads it.
    """

    task_name = "sim-machine"

    def __init__(self, controller: SimController, *, plant: ThermalPlant | None = None,
                 program: Program | None = None, seed: int = 0, period_s: float = 1.0,
                 speedup: float = 1.0, repeat: bool = True, record: bool = False,
                 max_rows: int | None = None, probe_every_s: float | None = None,
                 probe_noise_um: float = 0.5) -> None:
        super().__init__(HISTORY_COLUMNS, program=program, plant=plant, seed=seed,
                         period_s=period_s, speedup=speedup, repeat=repeat, record=record,
                         max_rows=max_rows)
        self.controller = controller
        if probe_every_s is not None and not (math.isfinite(probe_every_s)
                                              and probe_every_s > 0):
            raise ValueError(f"probe_every_s must be a positive number, got {probe_every_s!r}")
        if not (math.isfinite(probe_noise_um) and probe_noise_um >= 0):
            raise ValueError(f"probe_noise_um must be >= 0, got {probe_noise_um!r}")
        self.probe_every_s = probe_every_s
        self.probe_noise_um = probe_noise_um
        #: measurements made so far (the counter the controller shows)
        self.probes = 0
        self._next_probe_s = probe_every_s
        self._spoil_um = 0.0
        self._probe_rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(13,)))

    def spoil_next_probe(self, error_um: float) -> None:
        """Add `error_um` to the next measurement only (a bad probe)."""
        self._spoil_um = float(error_um)

    def _measure(self) -> dict[str, float]:
        """The measuring cycle's values when one is due (see the module), else {}."""
        due = self._next_probe_s
        if due is None or self.plant.time_s + 1e-9 < due:
            return {}
        every = self.probe_every_s or 0.0
        self._next_probe_s = due + every * max(1, math.floor((self.plant.time_s - due)
                                                             / every) + 1)
        value = (self.plant.growth_um() - self.plant.offset_um + self._spoil_um
                 + self.probe_noise_um * float(self._probe_rng.standard_normal()))
        self._spoil_um = 0.0
        self.probes += 1
        return {"probe_value": value, "probe_counter": float(self.probes % 65536)}

    async def _apply_outputs(self) -> None:
        outs = await self.controller.outputs()
        offset = outs.get("offset")
        if offset is not None and math.isfinite(offset):
            self.plant.offset_um = float(offset)

    async def _publish(self) -> dict[str, float]:
        sensors = self.plant.sensors()
        await self.controller.publish({**sensors, **self._measure()})
        if self.record:
            self._history.append((self.plant.time_s, *(sensors[c] for c in CHANNELS),
                                  self.plant.offset_um))
        return sensors

    async def prime(self) -> dict[str, float]:
        """Publish the current state without advancing (the values a client
        sees before the first tick); `run()` does this once by itself."""
        await self._apply_outputs()
        self._primed = True
        return await self._publish()

    async def tick(self) -> dict[str, float]:
        """Advance one period, apply the written offset, publish; return the
        published sensor values."""
        self.advance()
        await self._apply_outputs()
        self.ticks += 1
        return await self._publish()
