"""A simulated machine: the thermal plant behind a simulated controller.

Each tick advances the plant by `period_s` of machine time at the program's
speed, reads what the daemon wrote (`controller.outputs()`) and applies the
``offset`` (µm) to the plant, then publishes `plant.sensors()` (so the
published ``error_um`` = growth - the offset in force at that instant) and,
if asked, records the row.

Scheduling (`tick`, `run`, `start`/`stop`) and the history come from
`drivers.sim.runner.PlantRunner`.
"""

from __future__ import annotations

import math

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
                 max_rows: int | None = None) -> None:
        super().__init__(HISTORY_COLUMNS, program=program, plant=plant, seed=seed,
                         period_s=period_s, speedup=speedup, repeat=repeat, record=record,
                         max_rows=max_rows)
        self.controller = controller

    async def _apply_outputs(self) -> None:
        outs = await self.controller.outputs()
        offset = outs.get("offset")
        if offset is not None and math.isfinite(offset):
            self.plant.offset_um = float(offset)

    async def _publish(self) -> dict[str, float]:
        sensors = self.plant.sensors()
        await self.controller.publish(sensors)
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
