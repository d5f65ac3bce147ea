"""Test doubles for code built on compd, shipped with it (as structlog ships
`structlog.testing`): a fake clock (and one asyncio code can sleep on), an
in-memory controller and a recording wrapper for any driver. No pytest, no
sockets, no patching of the event loop.

- `FakeClock`: machine or monotonic time that moves only when told. Call it
  for the current reading (so it can stand in for `time.monotonic`, e.g.
  ``Daemon(cfg, clock=clock)``); `tick()` moves one period, `advance(s)` any
  amount. Hours of a pure `compd.core.cycle.Cycle` run in milliseconds::

      clock = FakeClock(period_s=1.0)
      for _ in range(3600):
          t = clock.tick()
          plan = cycle.plan(t, {"bearing": Sample(25.0, t), "ambient": Sample(20.0, t)})
          row = cycle.commit(WRITTEN)       # plan.writes reached the controller

- `SteppedClock`: a `FakeClock` that asyncio code can sleep on. Give the
  daemon its reading and its sleep (``Daemon(cfg, clock=clock,
  sleep=clock.sleep)``): the daemon runs a cycle, then waits until the test
  moves the clock to its next deadline. `cycle_done(n)` waits (on an event,
  never on wall time) until the daemon is asleep again, so a test steps it
  one cycle at a time, in lockstep with whatever else it steps, and a slow
  machine only makes the test slower (several daemons may share one clock:
  `due()` says how many sleepers the next tick wakes)::

      clock = SteppedClock(period_s=60.0)
      task = asyncio.create_task(Daemon(cfg, clock=clock, sleep=clock.sleep).run())
      await clock.cycle_done(1)             # the first cycle ran
      for _ in range(60):
          await machine.tick()              # the plant: one period on
          clock.tick()                      # the daemon's deadline: one cycle
          await clock.cycle_done(clock.sleeps + 1)

- `MemoryDriver`: a `drivers.base.Driver` whose controller is a dict. The test
  sets channel values (`set`), reads what the daemon wrote (`outputs`,
  `writes`), and makes the next read or write fail with any
  `drivers.errors.DriverError` (`fail_next_read`, `fail_next_write`). Unknown
  names raise `BadAddress`, as a real driver does; after `close()` reads and
  writes raise `ConnectionLost` until `connect()`.

- `RecordingDriver`: wraps a driver (a real one against a simulated
  controller, or a `MemoryDriver`) and remembers, per write, the offset read
  back in that cycle and the offset written.

These are for unit tests of the cycle and the shell. Protocol behaviour
(timeouts, reconnects, data types on the wire) is tested against the
simulated controllers of `drivers.sim` on 127.0.0.1, never against these.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Iterable, Mapping, Sequence

from drivers.base import Driver, Quality, Sample
from drivers.errors import BadAddress, ConnectionLost, DriverError

__all__ = ["FakeClock", "MemoryDriver", "RecordingDriver", "SteppedClock"]


class FakeClock:
    """Seconds that move only when told (starting at `start_s`)."""

    def __init__(self, period_s: float = 1.0, start_s: float = 0.0) -> None:
        self.now_s = start_s
        self.period_s = period_s

    def __call__(self) -> float:
        return self.now_s

    def tick(self) -> float:
        """Move one period on; returns the new reading."""
        self.now_s += self.period_s
        return self.now_s

    def advance(self, seconds: float) -> float:
        """Move `seconds` on (a stall, a jump); returns the new reading."""
        self.now_s += seconds
        return self.now_s


class SteppedClock(FakeClock):
    """A `FakeClock` with an asyncio `sleep` that ends only when the clock is
    moved past its deadline (by `tick`, `advance` or `set`).

    `tick()` lands exactly on ``start_s + k * period_s`` (k ticks so far), so a
    schedule of absolute deadlines on the same grid never sees rounding as
    lateness. `sleeps` counts the sleeps begun; `cycle_done(n)` returns once
    the n-th has begun (the sleeper finished what it did before sleeping).
    """

    def __init__(self, period_s: float = 1.0, start_s: float = 0.0) -> None:
        super().__init__(period_s, start_s)
        self.start_s = start_s
        self.ticks = 0
        #: sleeps begun so far (a sleep of 0 s or less is not counted: it returns at once)
        self.sleeps = 0
        self._sleepers: list[tuple[float, asyncio.Future[None]]] = []
        self._waiters: list[tuple[int, asyncio.Future[None]]] = []

    def tick(self) -> float:
        self.ticks += 1
        return self.set(self.start_s + self.ticks * self.period_s)

    def advance(self, seconds: float) -> float:
        return self.set(self.now_s + seconds)

    def set(self, now_s: float) -> float:
        """Move the clock to `now_s` (never back) and wake the sleepers now due."""
        if now_s < self.now_s:
            raise ValueError(f"a monotonic clock does not go back ({now_s} < {self.now_s})")
        self.now_s = now_s
        for due, fut in list(self._sleepers):
            if due <= now_s + _SLACK_S and not fut.done():
                fut.set_result(None)
        return now_s

    @property
    def sleeping(self) -> int:
        """Sleeps begun and not yet ended."""
        return sum(1 for _, fut in self._sleepers if not fut.done())

    def due(self, at_s: float | None = None) -> int:
        """How many of the sleeps not yet ended a move to `at_s` would end
        (default: the next `tick`): with several sleepers on one clock (the
        machines of `compd run DIR`), how many cycles that move starts."""
        if at_s is None:
            at_s = self.start_s + (self.ticks + 1) * self.period_s
        return sum(1 for due, fut in self._sleepers
                   if due <= at_s + _SLACK_S and not fut.done())

    async def sleep(self, seconds: float) -> None:
        """Return when the clock reads at least now + `seconds` (at once if <= 0)."""
        if seconds <= _SLACK_S:
            await asyncio.sleep(0)
            return
        fut: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        entry = (self.now_s + seconds, fut)
        self._sleepers.append(entry)
        self.sleeps += 1
        for waiter in self._waiters:
            if waiter[0] <= self.sleeps and not waiter[1].done():
                waiter[1].set_result(None)
        try:
            await fut
        finally:
            self._sleepers.remove(entry)

    async def cycle_done(self, n: int) -> None:
        """Wait until `n` sleeps have begun (`sleeps` >= n)."""
        if self.sleeps >= n:
            return
        fut: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        entry = (n, fut)
        self._waiters.append(entry)
        try:
            await fut
        finally:
            self._waiters.remove(entry)


#: a deadline this close to the clock's reading is reached (float rounding)
_SLACK_S = 1e-9


class MemoryDriver:
    """An in-memory controller behind the `Driver` interface.

    `channels` are the names it may read (with a starting value each),
    `outputs` the names it may write (read back as 0.0 until written). Sample
    timestamps come from `wall` (the daemon compares them with its wall
    clock for staleness): `time.time` unless a test passes its own.
    """

    protocol = "memory"

    def __init__(self, channels: Mapping[str, float], outputs: Iterable[str] = ("offset",),
                 *, wall: Callable[[], float] = time.time) -> None:
        self.values: dict[str, tuple[float, Quality]] = {
            name: (float(v), Quality.GOOD) for name, v in channels.items()}
        self.outputs: dict[str, float] = dict.fromkeys(outputs, 0.0)
        #: every successful write, in order
        self.writes: list[dict[str, float]] = []
        #: raised (once) by the next connect / read / write, then cleared
        self.fail_next_connect: DriverError | None = None
        self.fail_next_read: DriverError | None = None
        self.fail_next_write: DriverError | None = None
        self.reads = 0
        self.wall = wall
        self._connected = False

    def set(self, name: str, value: float, quality: Quality = Quality.GOOD) -> None:
        """What the controller will report for channel `name` from now on."""
        if name not in self.values:
            raise BadAddress(f"unknown channel {name!r}", channel=name)
        self.values[name] = (float(value), quality)

    @property
    def connected(self) -> bool:
        return self._connected

    async def connect(self) -> None:
        if self.fail_next_connect is not None:
            exc, self.fail_next_connect = self.fail_next_connect, None
            raise exc
        self._connected = True

    async def read(self, names: Sequence[str]) -> dict[str, Sample]:
        self._check_link()
        self.reads += 1
        if self.fail_next_read is not None:
            exc, self.fail_next_read = self.fail_next_read, None
            raise exc
        now = self.wall()
        got: dict[str, Sample] = {}
        for name in names:
            if name in self.values:
                value, quality = self.values[name]
                got[name] = Sample(value, now, quality)
            elif name in self.outputs:
                got[name] = Sample(self.outputs[name], now)
            else:
                raise BadAddress(f"unknown channel {name!r}", channel=name)
        return got

    async def write(self, values: Mapping[str, float]) -> None:
        self._check_link()
        unknown = [name for name in values if name not in self.outputs]
        if unknown:
            raise BadAddress(f"unknown output {unknown[0]!r}", channel=unknown[0])
        if self.fail_next_write is not None:
            exc, self.fail_next_write = self.fail_next_write, None
            raise exc
        self.outputs.update({name: float(v) for name, v in values.items()})
        self.writes.append(dict(values))

    async def close(self) -> None:
        self._connected = False

    def _check_link(self) -> None:
        if not self._connected:
            raise ConnectionLost("memory driver: not connected")


class RecordingDriver:
    """Forwards to a driver and remembers every read-back and write."""

    def __init__(self, inner: Driver, offset_name: str = "offset") -> None:
        self.inner = inner
        self.protocol = inner.protocol
        self.offset_name = offset_name
        #: (offset read back this cycle or None, offset written or None)
        self.cycles: list[tuple[float | None, float | None]] = []
        self._readback: float | None = None

    @property
    def connected(self) -> bool:
        return self.inner.connected

    async def connect(self) -> None:
        await self.inner.connect()

    async def read(self, names: Sequence[str]) -> dict[str, Sample]:
        self._readback = None
        got = await self.inner.read(names)
        if self.offset_name in got:
            self._readback = got[self.offset_name].value
        return got

    async def write(self, values: Mapping[str, float]) -> None:
        self.cycles.append((self._readback, values.get(self.offset_name)))
        await self.inner.write(values)

    async def close(self) -> None:
        await self.inner.close()
