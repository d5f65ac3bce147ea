"""The OPC UA driver's deadline: asyncua's cancellation subclass becomes a timeout."""

from __future__ import annotations

import asyncio

import pytest

from drivers.opcua import _deadline


class LibraryCancelled(asyncio.CancelledError):
    """Stands in for wait_for2's CancelledWithResultError (a CancelledError subclass)."""


async def _library_call() -> None:
    try:
        await asyncio.sleep(10)
    except asyncio.CancelledError:
        raise LibraryCancelled() from None


async def test_library_cancellation_at_our_deadline_is_a_timeout() -> None:
    with pytest.raises(TimeoutError):
        async with _deadline(0.01):
            await _library_call()
    await asyncio.sleep(0)  # the task itself is not left cancelled
    assert asyncio.current_task().cancelling() == 0  # type: ignore[union-attr]


async def test_a_real_cancellation_of_the_caller_still_propagates() -> None:
    async def caller() -> None:
        async with _deadline(5.0):
            await _library_call()
    task = asyncio.create_task(caller())
    await asyncio.sleep(0.01)
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task
