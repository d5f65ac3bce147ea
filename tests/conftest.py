"""Project-wide test rules: warnings are errors (pyproject), and an async test
that leaves asyncio tasks behind fails. And `listener`, a socket on 127.0.0.1
that listens and must never see a connection (the endpoint of configs that
must be refused before anything connects), and `rec`, a simulated Modbus
controller on 127.0.0.1 that records every offset the daemon writes
(`tests.faults.daemon_run.RecordingSim`)."""

from __future__ import annotations

import asyncio
import functools
import inspect
import os
import socket
from collections.abc import AsyncIterator, Callable, Coroutine, Iterator
from typing import TYPE_CHECKING, Any

import pytest
from hypothesis import settings

if TYPE_CHECKING:
    from tests.faults.daemon_run import RecordingSim

# Property tests search the same examples on every run (a fixed seed per test):
# a new counterexample is found when a test or its code changes, not at random
# in somebody else's CI run. HYPOTHESIS_PROFILE=explore searches afresh.
settings.register_profile("ci", derandomize=True, print_blob=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


def _guard(fn: Callable[..., Coroutine[Any, Any, Any]]) -> Callable[..., Coroutine[Any, Any, Any]]:
    @functools.wraps(fn)
    async def wrapper(*args: Any, **kwargs: Any) -> Any:
        before = asyncio.all_tasks()
        result = await fn(*args, **kwargs)
        for _ in range(20):  # let cancelled tasks finish unwinding
            leaked = asyncio.all_tasks() - before - {asyncio.current_task()}
            if not leaked:
                return result
            await asyncio.sleep(0.01)
        names = sorted(t.get_name() + ":" + repr(t.get_coro()) for t in leaked)
        pytest.fail(f"test left {len(leaked)} asyncio task(s) running: {names}")
    return wrapper


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        obj = getattr(item, "obj", None)
        if obj is not None and inspect.iscoroutinefunction(obj) and not getattr(
                item.get_closest_marker("allow_leaked_tasks"), "name", None):
            item.obj = _guard(obj)  # type: ignore[attr-defined]


@pytest.fixture(scope="module")
def listener() -> Iterator[socket.socket]:
    """A socket on a free 127.0.0.1 port that listens and must never see a connection
    (non-blocking: `accept()` raising BlockingIOError says nobody came)."""
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    sock.listen(16)
    sock.setblocking(False)
    try:
        yield sock
    finally:
        sock.close()


@pytest.fixture
async def rec() -> AsyncIterator[RecordingSim]:
    """A simulated Modbus controller (bearing and ambient at 20 °C) that records
    every offset written to it, stopped after the test."""
    from tests.faults.daemon_run import RecordingSim

    r = RecordingSim()
    await r.start()
    try:
        yield r
    finally:
        await r.stop()
