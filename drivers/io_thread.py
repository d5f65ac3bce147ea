"""One dedicated worker thread for a blocking protocol library.

Blocking libraries (python-snap7, the FOCAS shared library) are driven from
exactly one thread per driver: FOCAS handles are not thread-safe and a snap7
client must not see two requests at once. `IoThread.call` runs a function
there and bounds the wait with `asyncio.wait_for`, so the event loop never
blocks; the function itself should also bound its own I/O (socket timeouts,
library timeouts) so that an abandoned call frees the thread soon after.
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

T = TypeVar("T")


class IoThread:
    """A single-thread executor owned by one driver."""

    def __init__(self, name: str) -> None:
        self._name = name
        self._executor: ThreadPoolExecutor | None = None
        self._thread_ids: set[int] = set()

    def _ensure(self) -> ThreadPoolExecutor:
        if self._executor is None:
            self._executor = ThreadPoolExecutor(
                max_workers=1, thread_name_prefix=self._name, initializer=self._register)
        return self._executor

    def _register(self) -> None:
        self._thread_ids.add(threading.get_ident())

    @property
    def thread_ids(self) -> frozenset[int]:
        """Identities of the worker threads ever used (one per open/close life)."""
        return frozenset(self._thread_ids)

    async def call(self, fn: Callable[[], T], timeout_s: float) -> T:
        """Run `fn` on the worker thread; `TimeoutError` after `timeout_s`."""
        loop = asyncio.get_running_loop()
        fut = loop.run_in_executor(self._ensure(), fn)
        return await asyncio.wait_for(fut, timeout_s)

    def shutdown(self) -> None:
        """Stop accepting work; a call still running finishes on its own."""
        if self._executor is not None:
            self._executor.shutdown(wait=False, cancel_futures=True)
            self._executor = None
