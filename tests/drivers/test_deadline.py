"""The deadline around every controller call: a library's cancellation subclass (asyncua's
wait_for2) becomes a timeout at whichever deadline expires, inner or outer."""

from __future__ import annotations

import asyncio

import pytest

from drivers.backoff import Backoff
from drivers.deadline import deadline
from drivers.errors import ControllerTimeout
from drivers.link import Link


class LibraryCancelled(asyncio.CancelledError):
    """Stands in for wait_for2's CancelledWithResultError (a CancelledError subclass)."""


async def _library_call() -> None:
    try:
        await asyncio.sleep(10)
    except asyncio.CancelledError:
        raise LibraryCancelled() from None


async def test_library_cancellation_at_our_deadline_is_a_timeout() -> None:
    with pytest.raises(TimeoutError):
        async with deadline(0.01):
            await _library_call()
    await asyncio.sleep(0)  # the task itself is not left cancelled
    assert asyncio.current_task().cancelling() == 0  # type: ignore[union-attr]


async def test_a_real_cancellation_of_the_caller_still_propagates() -> None:
    async def caller() -> None:
        async with deadline(5.0):
            await _library_call()
    task = asyncio.create_task(caller())
    await asyncio.sleep(0.01)
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task


async def test_an_outer_deadline_that_expires_first_is_a_timeout_not_a_cancellation() -> None:
    """The cycle's read scope (or a connect attempt) around the driver's own deadline:
    when the outer one expires first, the library's subclass passes the inner one (not
    its expiry) and the outer one ends it as a timeout; the task is not left cancelled."""
    with pytest.raises(TimeoutError):
        async with deadline(0.01), deadline(10.0):
            await _library_call()
    await asyncio.sleep(0)
    assert asyncio.current_task().cancelling() == 0  # type: ignore[union-attr]


async def test_asyncio_timeout_alone_lets_the_subclass_escape() -> None:
    """Why every scope is a `deadline`: `asyncio.timeout` ends only the exact
    CancelledError as a timeout, and the subclass escapes it as a cancellation."""
    with pytest.raises(LibraryCancelled):
        async with asyncio.timeout(0.01):
            await _library_call()


async def test_a_block_that_ends_in_time_is_untouched() -> None:
    async with deadline(5.0):
        await asyncio.sleep(0)
    with pytest.raises(ValueError, match="own error"):
        async with deadline(5.0):
            raise ValueError("own error")


async def test_a_connect_whose_library_races_its_deadline_is_a_timed_out_connect() -> None:
    """A connect attempt past `connect_timeout_s`, its library ending with the
    subclass: the caller is told the connect timed out (and the backoff starts), not
    that the driver was closed."""
    dropped: list[object] = []

    async def drop(session: object, graceful: bool) -> None:
        dropped.append(session)

    link: Link[object] = Link("opc.tcp://127.0.0.1:1", Backoff(), 0.01, open=_library_open,
                              drop=drop, connect_timeout_s=0.02)
    with pytest.raises(ControllerTimeout, match=r"connect to .* timed out"):
        await link.connect()
    assert not link.backoff.ready()
    assert link.session is None and not dropped


async def _library_open() -> object:
    await _library_call()
    return object()
