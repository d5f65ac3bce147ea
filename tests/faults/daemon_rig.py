"""The in-process daemon against a simulated controller, for the fault tests.

`DaemonRig` builds a daemon config for the sim (`compd.offline.demo.daemon_config`,
then the test's overrides), wraps the real driver in `InvariantDriver` (every
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
from pathlib import Path
from typing import Any

from compd.config.loader import LoadedConfig, parse_config
from compd.offline.demo import daemon_config
from compd.runtime.daemon import Daemon
from compd.runtime.driver_setup import build_driver
from compd.runtime.sdnotify import Notifier
from compd.testing import SteppedClock
from drivers.sim.base import SimController
from tests.faults.invariants import InvariantDriver, Invariants

Plant = Callable[[int, float], Awaitable[None]]


class EventLog:
    """Stands in for the daemon's structlog logger: keeps (level, event, fields)."""

    def __init__(self) -> None:
        self.events: list[tuple[str, str, dict[str, Any]]] = []

    def _at(self, level: str) -> Callable[..., None]:
        def log(event: str, **fields: Any) -> None:
            if level != "debug":
                self.events.append((level, event, fields))
        return log

    def __getattr__(self, level: str) -> Callable[..., None]:
        return self._at(level)

    def names(self) -> list[str]:
        return [e for _, e, _ in self.events]


def merge(doc: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    for key, value in overrides.items():
        if isinstance(value, dict) and isinstance(doc.get(key), dict):
            merge(doc[key], value)
        else:
            doc[key] = value
    return doc


def make_config(sim: SimController, tmp_path: Path, *, time_scale: float,
                overrides: dict[str, Any] | None = None, model: str = "sp2",
                slew_um_s: float = 1.0, limit_um: float = 100.0) -> LoadedConfig:
    doc = daemon_config(sim, model=model, period_s=1.0, time_scale=time_scale,
                        state_dir=tmp_path / "state", limit_um=limit_um,
                        slew_um_s=slew_um_s, extra_channels=())
    doc["recorder"] = {"enabled": False}
    merge(doc, overrides or {})
    return parse_config(doc, tmp_path / "compd.toml")


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

    async def _pace(self, clock: SteppedClock, goal: Callable[[], bool]) -> None:
        """Each time the daemon sleeps, move the clock to its next deadline, until
        `goal` holds after a cycle: then the clock stays, and so does the daemon (a
        condition on the cycles is met at that cycle, however late the test looks)."""
        while True:
            await clock.cycle_done(clock.ticks + 1)
            if goal():
                return
            clock.tick()

    async def start(self) -> None:
        self._task = asyncio.create_task(self.daemon.run())

    async def until(self, predicate: Callable[[], bool], limit_s: float = 120.0) -> None:
        """Wait for `predicate`; fail if the daemon ended or time ran out (real time).
        Stepped: the clock moves until the predicate holds after a cycle, then stops,
        so the daemon is held at that cycle."""
        loop = asyncio.get_running_loop()
        end = loop.time() + limit_s
        if self.clock is not None and self._task is not None and not predicate():
            pacer = self._pacer = asyncio.create_task(self._pace(self.clock, predicate))
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
        while not predicate():
            if self._task is not None and self._task.done():
                self._task.result()  # raises what the daemon raised
                raise AssertionError("the daemon stopped before the condition")
            if loop.time() > end:
                raise AssertionError(f"condition not reached in {limit_s} s "
                                     f"({self.daemon.loop.cycles} cycles)")
            await asyncio.sleep(0.002)

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
