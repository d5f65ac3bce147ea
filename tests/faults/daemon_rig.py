"""The in-process daemon against a simulated controller, for the fault tests.

`DaemonRig` takes a daemon config for the sim (`tests.configs.make_config`: the
sim's own addresses, then the test's overrides), wraps the real driver in `InvariantDriver` (every
write checked) and runs `Daemon.run()` as a task at a fast time scale. The
test's plant callback runs before every read with the read's index and the
machine time of that sample (estimated from the daemon's last cycle), and
writes the controller's memory the way the machine would.

With ``stepped=True`` the daemon's clock is a `compd.testing.SteppedClock`
moved to each next deadline as soon as the daemon sleeps: cycles follow each
other as fast as the machine allows, never late (no overrun, no skipped
deadline, exactly one machine period between two samples), whatever the load.
`wall` replaces the daemon's wall clock (sample ages, the rows' ``wall_s``).
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from typing import Any

from compd.config.loader import LoadedConfig
from compd.runtime.daemon import Daemon
from compd.runtime.driver_setup import build_driver
from compd.runtime.sdnotify import Notifier
from compd.testing import SteppedClock
from drivers.sim.base import SimController
from tests.faults.invariants import InvariantDriver, Invariants
from tests.harness import EventLog, pace, until

Plant = Callable[[int, float], Awaitable[None]]


class DaemonRig:
    def __init__(self, sim: SimController, cfg: LoadedConfig, inv: Invariants,
                 plant: Plant | None = None, *, stepped: bool = False,
                 wall: Callable[[], float] | None = None) -> None:
        self.sim = sim
        self.cfg = cfg
        self.inv = inv
        self.plant = plant
        self.driver = InvariantDriver(build_driver(cfg), inv, self._before_read)
        self.clock: SteppedClock | None = None
        # the daemon's own wall clock (time.time as bound when compd loaded) unless
        # the test gives one
        walls: dict[str, Any] = {} if wall is None else {"wall": wall}
        if stepped:
            self.clock = SteppedClock(period_s=cfg.real_period_s)
            self.daemon = Daemon(cfg, driver=self.driver, notifier=Notifier(None),
                                 clock=self.clock, sleep=self.clock.sleep, **walls)
        else:
            self.daemon = Daemon(cfg, driver=self.driver, notifier=Notifier(None), **walls)
        self._pacer: asyncio.Task[None] | None = None
        self.log = EventLog()
        self.daemon.journal.log = self.log
        self._task: asyncio.Task[int] | None = None

    @property
    def machine_s(self) -> float:
        """Machine time of the next sample (the last cycle's + one period)."""
        r = self.daemon.loop.last_result
        if r is None or r.record is None:
            return 0.0
        return r.record.mono_s + self.cfg.period_s

    async def _before_read(self, index: int) -> None:
        if self.plant is not None:
            await self.plant(index, self.machine_s)

    async def start(self) -> None:
        self._task = asyncio.create_task(self.daemon.run())

    async def until(self, predicate: Callable[[], bool], limit_s: float = 120.0) -> None:
        """Wait for `predicate`; fail if the daemon ended or time ran out (real time).
        Stepped: the clock moves until the predicate holds after a cycle, then stops,
        so the daemon is held at that cycle."""
        loop = asyncio.get_running_loop()
        end = loop.time() + limit_s
        if self.clock is not None and self._task is not None and not predicate():
            pacer = self._pacer = asyncio.create_task(pace(self.clock, predicate))
            done, _ = await asyncio.wait({pacer, self._task}, timeout=limit_s,
                                         return_when=asyncio.FIRST_COMPLETED)
            if self._task in done:
                self._task.result()  # raises what the daemon raised
                raise AssertionError("the daemon stopped before the condition")
            if pacer not in done:
                raise AssertionError(f"condition not reached in {limit_s} s "
                                     f"({self.daemon.loop.cycles} cycles)")
            pacer.result()
            return
        await until(predicate, what=f"condition ({self.daemon.loop.cycles} cycles)",
                    limit_s=max(0.0, end - loop.time()), task=self._task, every_s=0.002)

    async def stop(self) -> int:
        if self._task is None:
            return 0
        self.daemon.request_stop()
        try:
            rc = await asyncio.wait_for(self._task, 120.0)
        finally:
            pacer, self._pacer = self._pacer, None
            if pacer is not None:
                pacer.cancel()
                await asyncio.gather(pacer, return_exceptions=True)
        self._task = None
        return rc

    async def run_until(self, predicate: Callable[[], bool], limit_s: float = 120.0) -> int:
        await self.start()
        try:
            await self.until(predicate, limit_s)
        finally:
            rc = await self.stop()
        return rc
