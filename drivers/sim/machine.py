"""A simulated machine: the thermal plant behind a simulated controller.

Each tick advances the plant by `period_s` of machine time at the program's
speed, reads what the daemon wrote (`controller.outputs()`) and applies the
``offset`` (µm) to the plant, then publishes `plant.sensors()` (so the
published ``error_um`` = growth - the offset in force at that instant) and,
if asked, records the row.

Ticks come either one by one (`await machine.tick()`, for tests) or from
`run()` / `start()`+`stop()`, scheduled by absolute deadlines on the event
loop's monotonic clock: tick k is due at t0 + k·period_s/speedup real seconds.
`speedup` X means one machine second per 1/X real seconds. A late tick is
counted in `overruns` and the missed deadlines are skipped (no catch-up burst),
so machine time then runs slower than asked, never in jumps.
"""

from __future__ import annotations

import asyncio
import math

import numpy as np

from drivers.sim import CHANNELS
from drivers.sim.base import SimController
from drivers.sim.history import History
from drivers.sim.plant import ThermalPlant
from drivers.sim.programs import Program, make_program

#: columns of a recorded row (besides the standard channels)
HISTORY_COLUMNS: tuple[str, ...] = ("time_s", *CHANNELS, "offset_um")


class SimMachine:
    """Couples a `ThermalPlant` to any `SimController`.

    The caller owns the controller's lifecycle (`start()`/`stop()` of the
    server); the machine only publishes to it and reads it.
    """

    def __init__(self, controller: SimController, *, plant: ThermalPlant | None = None,
                 program: Program | None = None, seed: int = 0, period_s: float = 1.0,
                 speedup: float = 1.0, repeat: bool = True, record: bool = False,
                 max_rows: int | None = None) -> None:
        if not (period_s > 0.0 and math.isfinite(period_s)):
            raise ValueError(f"period_s must be a positive finite number, got {period_s!r}")
        if not (speedup > 0.0 and math.isfinite(speedup)):
            raise ValueError(f"speedup must be a positive finite number, got {speedup!r}")
        self.controller = controller
        self.program = program if program is not None else make_program("spectrum", seed=seed)
        self.plant = plant if plant is not None else ThermalPlant(
            seed=seed, params=self.program.plant_params())
        self.period_s = float(period_s)
        self.speedup = float(speedup)
        #: run the program again from its start when it ends (else: spindle stands)
        self.repeat = repeat
        self.record = record
        self.ticks = 0
        self.overruns = 0
        self._history = History(HISTORY_COLUMNS, max_rows)
        self._stop = asyncio.Event()
        self._task: asyncio.Task[None] | None = None
        self._primed = False

    @property
    def time_s(self) -> float:
        """Machine time, s."""
        return self.plant.time_s

    def speed_at(self, t_s: float) -> float:
        """The program's spindle speed at machine time `t_s`."""
        duration = self.program.duration_s
        if self.repeat and duration > 0.0:
            t_s = math.fmod(t_s, duration)
        return self.program(t_s)

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
        self.plant.step(self.period_s, self.speed_at(self.plant.time_s), self.program.load)
        await self._apply_outputs()
        self.ticks += 1
        return await self._publish()

    async def run(self, *, until_s: float | None = None) -> None:
        """Tick on real-time deadlines until `stop()` or machine time `until_s`."""
        loop = asyncio.get_running_loop()
        self._stop.clear()
        if not self._primed:
            await self.prime()
        real_period_s = self.period_s / self.speedup
        deadline = loop.time() + real_period_s
        while until_s is None or self.plant.time_s < until_s:
            delay = deadline - loop.time()
            if delay > 0.0:
                try:
                    async with asyncio.timeout(delay):
                        await self._stop.wait()
                    return
                except TimeoutError:
                    pass
            elif self._stop.is_set():
                return
            await self.tick()
            deadline += real_period_s
            late_s = loop.time() - deadline
            if late_s > 0.0:
                self.overruns += 1
                deadline += math.ceil(late_s / real_period_s) * real_period_s

    def start(self) -> asyncio.Task[None]:
        """Run in a background task (see `stop`)."""
        if self._task is not None and not self._task.done():
            raise RuntimeError("the machine is already running")
        self._stop.clear()
        self._task = asyncio.create_task(self.run(), name="sim-machine")
        return self._task

    async def stop(self) -> None:
        """Stop the background task after its current tick; re-raise its error."""
        self._stop.set()
        task, self._task = self._task, None
        if task is not None:
            await task

    @property
    def history(self) -> list[dict[str, float]]:
        """Recorded rows (with `record=True`): time_s, the channels, offset_um."""
        return self._history.rows()

    def history_arrays(self) -> dict[str, np.ndarray]:
        """Recorded rows as float64 columns keyed by `HISTORY_COLUMNS`."""
        return self._history.arrays()
