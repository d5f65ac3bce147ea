"""`compd.runtime.tasks.gather_with`: the machines' (or workers') tasks with a
watcher beside them; however they end, nothing is left running."""

from __future__ import annotations

import asyncio

import pytest

from compd.runtime.tasks import gather_with


async def test_a_task_that_raises_ends_the_watcher_and_the_others() -> None:
    forever = asyncio.Event()
    cancelled: list[str] = []

    async def waits(name: str) -> None:
        try:
            await forever.wait()
        except asyncio.CancelledError:
            cancelled.append(name)
            raise

    async def fails() -> None:
        await asyncio.sleep(0)
        raise RuntimeError("machine crashed")

    tasks = [asyncio.ensure_future(waits("other")), asyncio.ensure_future(fails())]
    watcher = asyncio.ensure_future(waits("watcher"))
    with pytest.raises(RuntimeError, match="machine crashed"):
        await gather_with(tasks, watcher)
    assert sorted(cancelled) == ["other", "watcher"]
    assert all(t.done() for t in [*tasks, watcher])


async def test_the_callers_cancellation_ends_everything() -> None:
    forever = asyncio.Event()
    tasks = [asyncio.ensure_future(forever.wait()) for _ in range(3)]
    watcher = asyncio.ensure_future(forever.wait())
    run = asyncio.ensure_future(gather_with(tasks, watcher))
    await asyncio.sleep(0)
    run.cancel()
    with pytest.raises(asyncio.CancelledError):
        await run
    assert all(t.cancelled() for t in [*tasks, watcher])
