"""The shell's one source of time: `Clock`, injected into the loop and every sink.

Three readings, each injectable (`compd.testing.SteppedClock` drives the loop
in lockstep: ``Clock(mono=clock, sleep=clock.sleep)``):

- `mono`: monotonic seconds: deadlines, machine time, rate limits of repeated
  log lines, the checkpoint's ``saved_mono_s``;
- `wall`: wall-clock seconds: sample ages, the recorder's rows, the last
  complete cycle that `compd health --state-dir` judges;
- `sleep`: the wait until the next deadline; None waits on the event loop's
  own timer (`pause`), which a stop request ends early.

The loop reads `mono` and `wall` once per cycle, at its start (`Clock.at`):
that `Instant` is the cycle's time for the cycle (`Cycle.plan`), its report
(`compd.core.plan.Row.machine_s`, ``wall_s``) and every sink (the recorder's
row, the metrics' last complete cycle, the checkpoint's). Nothing in the loop
or its sinks calls `time` itself.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass

__all__ = ["Clock", "Instant", "pause"]


@dataclass(frozen=True, slots=True)
class Instant:
    """One cycle's time, read once: machine seconds (the schedule's, what the
    cycle steps on), monotonic seconds and wall-clock seconds."""

    machine_s: float
    mono_s: float
    wall_s: float


@dataclass(frozen=True, slots=True)
class Clock:
    mono: Callable[[], float] = time.monotonic
    wall: Callable[[], float] = time.time
    sleep: Callable[[float], Awaitable[object]] | None = None

    def at(self, mono_s: float, machine_s: Callable[[float], float]) -> Instant:
        """The cycle's `Instant`: `mono_s` as read, its machine time, the wall clock now."""
        return Instant(machine_s(mono_s), mono_s, self.wall())


async def pause(clock: Clock, stop: asyncio.Event, delay_s: float) -> None:
    """Until `delay_s` has passed on `clock`, or `stop` is set."""
    if clock.sleep is None:
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(stop.wait(), delay_s)
        return
    stopped = asyncio.ensure_future(stop.wait())
    nap = asyncio.ensure_future(clock.sleep(max(0.0, delay_s)))
    try:
        await asyncio.wait({stopped, nap}, return_when=asyncio.FIRST_COMPLETED)
    finally:
        stopped.cancel()
        nap.cancel()
        await asyncio.gather(stopped, nap, return_exceptions=True)
