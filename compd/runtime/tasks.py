"""Tasks run with a watcher beside them (`compd run DIR`'s machines in one
process, `compd.runtime.fleet`, and its worker processes, `compd.runtime.workers`)."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Sequence
from typing import Any

__all__ = ["gather_with"]


async def gather_with(tasks: Sequence[asyncio.Task[Any]], watcher: asyncio.Task[Any]) -> None:
    """Await every task. However that ends (all done, one raised, the caller
    cancelled), the watcher is cancelled and awaited, then every task still
    running is cancelled and awaited (their exceptions are theirs: not raised
    here); the first task's exception, or the caller's cancellation, propagates."""
    try:
        await asyncio.gather(*tasks)
    finally:
        watcher.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await watcher
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
