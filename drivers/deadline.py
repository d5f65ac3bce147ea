"""A deadline for a controller call that ends as `TimeoutError` however the library
under it was cancelled.

asyncua waits with `wait_for2`, which, when a cancellation meets a request whose
answer arrived at the same instant, raises `CancelledWithResultError`, a *subclass*
of CancelledError. `asyncio.timeout` turns only the exact CancelledError into
TimeoutError, so at an expiring deadline the subclass would escape as if the
caller's task itself had been cancelled: a daemon's loop ended by its own read's
deadline. Every deadline around a controller call, the driver's own and any
scope around it (a connect attempt, the cycle's read), is this one: whichever
expires first ends as a timeout, and a real cancellation of the task still
propagates.
"""

from __future__ import annotations

import asyncio
from types import TracebackType


class deadline:  # noqa: N801 - used as `async with deadline(s):`, like asyncio.timeout
    """`async with deadline(seconds):` the block, or TimeoutError when it expires."""

    __slots__ = ("_timeout",)

    def __init__(self, seconds: float) -> None:
        self._timeout = asyncio.timeout(seconds)

    async def __aenter__(self) -> None:
        await self._timeout.__aenter__()

    async def __aexit__(self, exc_type: type[BaseException] | None,
                        exc: BaseException | None, tb: TracebackType | None) -> None:
        await self._timeout.__aexit__(exc_type, exc, tb)  # the exact CancelledError
        if exc_type is not None and issubclass(exc_type, asyncio.CancelledError) \
                and self._timeout.expired():
            task = asyncio.current_task()
            if task is None or task.cancelling() == 0:  # ours, not the task's own
                raise TimeoutError from None
