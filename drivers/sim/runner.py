"""What the simulated machine and the HIL drive loop share: a thermal plant
running a test program, ticked on real-time deadlines, and a run history.

Ticks come either one by one (`await runner.tick()`, for tests) or from
`run()` / `start()`+`stop()`, scheduled by absolute deadlines on the event
loop's monotonic clock: tick k is due at t0 + k·period_s/speedup real seconds.
`speedup` X means one machine second per 1/X real seconds. A late tick is
counted in `overruns` and the missed deadlines are skipped (no catch-up
burst), so machine time then runs slower than asked, never in jumps.
Subclasses say what one exchange with the controller is (`prime`, `tick`).
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Sequence

import numpy as np

from drivers.sim.history import History
from drivers.sim.plant import ThermalPlant
from drivers.sim.programs import Program, make_program


class PlantRunner:
    """A plant, its program and the deadline schedule that ticks it."""

    #: the asyncio task name of `start()`
    task_name = "sim-plant"

    def __init__(self, columns: Sequence[str], *, program: Program | None = None,
                 plant: ThermalPlant | None = None, seed: int = 0, period_s: float = 1.0,
                 speedup: float = 1.0, repeat: bool = True, record: bool = False,
                 max_rows: int | None = None) -> None:
        if not (period_s > 0.0 and math.isfinite(period_s)):
            raise ValueError(f"period_s must be a positive finite number, got {period_s!r}")
        if not (speedup > 0.0 and math.isfinite(speedup)):
            raise ValueError(f"speedup must be a positive finite number, got {speedup!r}")
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
        self._history = History(columns, max_rows)
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

    def advance(self) -> None:
        """Step the plant one period at the program's speed and load (the
        subclass counts the tick when its exchange has reached that point)."""
        self.plant.step(self.period_s, self.speed_at(self.plant.time_s), self.program.load)

    async def prime(self) -> dict[str, float]:
        raise NotImplementedError

    async def tick(self) -> dict[str, float]:
        raise NotImplementedError

    async def _finish(self) -> None:
        """Called when `run()` ends, however it ends."""

    # -- scheduling --------------------------------------------------------------

    async def run(self, *, until_s: float | None = None) -> None:
        """Tick on real-time deadlines until `stop()` or machine time `until_s`."""
        loop = asyncio.get_running_loop()
        self._stop.clear()
        try:
            if not self._primed:
                await self.prime()
            real_period_s = self.period_s / self.speedup
            deadline = loop.time() + real_period_s
            while until_s is None or self.plant.time_s < until_s - 1e-9:
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
        finally:
            await self._finish()

    def start(self, *, until_s: float | None = None) -> asyncio.Task[None]:
        """Run in a background task (see `stop`)."""
        if self._task is not None and not self._task.done():
            raise RuntimeError(f"{type(self).__name__} is already running")
        self._stop.clear()
        self._task = asyncio.create_task(self.run(until_s=until_s), name=self.task_name)
        return self._task

    async def stop(self) -> None:
        """Stop after the current tick; re-raise the loop's error."""
        self._stop.set()
        task, self._task = self._task, None
        if task is not None:
            await task

    # -- the record ----------------------------------------------------------------

    @property
    def history(self) -> list[dict[str, float]]:
        """Recorded rows (with `record=True`) keyed by the runner's columns."""
        return self._history.rows()

    def history_arrays(self) -> dict[str, np.ndarray]:
        """Recorded rows as float64 columns keyed by the runner's columns."""
        return self._history.arrays()
