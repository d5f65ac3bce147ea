"""CPU per pause between cycles: `compd.runtime.clock.pause` (a timeout in the
caller's task) against `asyncio.wait_for` around the stop event (a task per
pause), with many tasks pausing together as the machines of `compd run DIR` do.

Run:  .venv/bin/python benchmarks/bench_loop_pause.py [--tasks 500] [--pauses 40]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import time
from collections.abc import Awaitable, Callable

from compd.runtime.clock import Clock, pause

DELAY_S = 0.002


async def wait_for_pause(stop: asyncio.Event) -> None:
    with contextlib.suppress(TimeoutError):
        await asyncio.wait_for(stop.wait(), DELAY_S)


async def compd_pause(stop: asyncio.Event) -> None:
    await pause(Clock(), stop, DELAY_S)


async def cpu_per_pause(fn: Callable[[asyncio.Event], Awaitable[None]],
                        tasks: int, pauses: int) -> float:
    """CPU microseconds per pause, `tasks` tasks each pausing `pauses` times."""
    stop = asyncio.Event()

    async def one() -> None:
        for _ in range(pauses):
            await fn(stop)

    c0 = time.process_time()
    await asyncio.gather(*(one() for _ in range(tasks)))
    return (time.process_time() - c0) / (tasks * pauses) * 1e6


async def main(tasks: int, pauses: int) -> None:
    print(f"{tasks} tasks x {pauses} pauses of {DELAY_S * 1e3:.0f} ms; CPU µs per pause")
    for _ in range(3):
        old = await cpu_per_pause(wait_for_pause, tasks, pauses)
        new = await cpu_per_pause(compd_pause, tasks, pauses)
        print(f"  asyncio.wait_for {old:6.1f}   compd pause {new:6.1f}   ({old / new:.2f}x)")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tasks", type=int, default=500)
    ap.add_argument("--pauses", type=int, default=40)
    args = ap.parse_args()
    asyncio.run(main(args.tasks, args.pauses))
