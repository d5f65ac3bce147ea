"""A real driver stepped by a fake clock, for in-process daemon tests.

Before each read the clock moves one period and the test's plant publishes the
next inputs; after each cycle `note` sees the daemon's last result (a subclass
records what its test judges: the register in force, the status word…).
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable, Mapping, Sequence
from typing import Any

from compd.runtime.daemon import Daemon
from compd.testing import FakeClock
from drivers.base import Driver, Sample


class ClockedDriver:
    def __init__(self, inner: Driver, clock: FakeClock,
                 plant: Callable[[int], Awaitable[None]]) -> None:
        self.inner = inner
        self.protocol = inner.protocol
        self.clock = clock
        self.plant = plant
        self.daemon: Daemon | None = None
        self.reads = 0

    def note(self, result: Any) -> None:
        """The cycle just done (the daemon's last result): override to record it."""

    @property
    def connected(self) -> bool:
        return self.inner.connected

    async def connect(self) -> None:
        await self.inner.connect()

    async def read(self, names: Sequence[str]) -> dict[str, Sample]:
        self.clock.tick()
        r = self.daemon.loop.last_result if self.daemon is not None else None
        if r is not None:
            self.note(r)
        await self.plant(self.reads)
        self.reads += 1
        return await self.inner.read(names)

    async def write(self, values: Mapping[str, float]) -> None:
        await self.inner.write(values)

    async def close(self) -> None:
        await self.inner.close()
