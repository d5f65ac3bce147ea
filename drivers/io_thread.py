"""One dedicated worker thread for a blocking protocol library.

Blocking libraries (python-snap7, the FOCAS shared library) are driven from
exactly one thread per driver: FOCAS handles are not thread-safe and a snap7
client must not see two requests at once. `IoThread.call` runs a function
there and bounds the wait, so the event loop never blocks; the function
itself should also bound its own I/O (socket timeouts, library timeouts) so
that an abandoned call frees the thread soon after.

The hop is kept as lean as a hop can be, because a driver pays it on every
read and every write (benchmarks/bench_driver_s7.py): a plain thread takes
jobs from a `queue.SimpleQueue` and hands the outcome back with one
`loop.call_soon_threadsafe`; the timeout is one `loop.call_later` handle on
the job's asyncio future (no `concurrent.futures.Future` chained to an
asyncio one, no `wait_for` wrapper). A job whose caller gave up (timed out
or cancelled) before the thread reached it is skipped, as an executor skips
a cancelled future.
"""

from __future__ import annotations

import asyncio
import contextlib
import queue
import threading
import weakref
from collections.abc import Callable
from typing import Any, Generic, TypeVar

T = TypeVar("T")


class _Job(Generic[T]):
    __slots__ = ("abandoned", "fn", "fut", "loop")

    def __init__(self, fn: Callable[[], T], loop: asyncio.AbstractEventLoop,
                 fut: asyncio.Future[T]) -> None:
        self.fn = fn
        self.loop = loop
        self.fut = fut
        self.abandoned = False  # set on the loop thread, read on the worker


def _settle(fut: asyncio.Future[Any], result: Any, exc: BaseException | None) -> None:
    """On the loop thread: complete `fut` unless its caller already left."""
    if fut.done():
        return
    if exc is None:
        fut.set_result(result)
    else:
        fut.set_exception(exc)


def _expire(job: _Job[Any]) -> None:
    """On the loop thread: the call's time is up."""
    job.abandoned = True
    if not job.fut.done():
        job.fut.set_exception(TimeoutError())


def _serve(jobs: queue.SimpleQueue[_Job[Any] | None], started: Callable[[], None]) -> None:
    """The worker thread: run jobs in order until the `None` sentinel."""
    started()
    while True:
        job = jobs.get()
        if job is None:
            return
        if job.abandoned:
            continue
        try:
            result, exc = job.fn(), None
        except BaseException as e:  # handed to the caller, re-raised there
            result, exc = None, e
        with contextlib.suppress(RuntimeError):  # a closed loop: nobody waits any more
            job.loop.call_soon_threadsafe(_settle, job.fut, result, exc)
        del job, result, exc  # drop references before blocking on the queue


class IoThread:
    """A single worker thread owned by one driver (started on first use)."""

    def __init__(self, name: str) -> None:
        self._name = name
        self._jobs: queue.SimpleQueue[_Job[Any] | None] | None = None
        self._thread: threading.Thread | None = None
        self._thread_ids: set[int] = set()

    def _ensure(self) -> queue.SimpleQueue[_Job[Any] | None]:
        if self._jobs is None:
            jobs: queue.SimpleQueue[_Job[Any] | None] = queue.SimpleQueue()
            ids = self._thread_ids
            thread = threading.Thread(target=_serve, name=self._name, daemon=True,
                                      args=(jobs, lambda: ids.add(threading.get_ident())))
            thread.start()
            # an IoThread dropped without shutdown() still stops its thread
            weakref.finalize(self, jobs.put, None)
            self._jobs, self._thread = jobs, thread
        return self._jobs

    @property
    def thread_ids(self) -> frozenset[int]:
        """Identities of the worker threads ever used (one per open/close life)."""
        return frozenset(self._thread_ids)

    @property
    def alive(self) -> bool:
        """True while a worker thread of this IoThread is running."""
        return self._thread is not None and self._thread.is_alive()

    async def call(self, fn: Callable[[], T], timeout_s: float) -> T:
        """Run `fn` on the worker thread; `TimeoutError` after `timeout_s`."""
        loop = asyncio.get_running_loop()
        fut: asyncio.Future[T] = loop.create_future()
        job = _Job(fn, loop, fut)
        self._ensure().put(job)
        timer = loop.call_later(timeout_s, _expire, job)
        try:
            return await fut
        finally:
            timer.cancel()
            job.abandoned = True  # cancelled while queued: the thread skips it

    def shutdown(self) -> None:
        """Stop accepting work and stop the thread once idle: queued jobs are
        dropped (their callers get `CancelledError`), a call still running
        finishes on its own."""
        jobs, self._jobs, self._thread = self._jobs, None, None
        if jobs is None:
            return
        while True:
            try:
                job = jobs.get_nowait()
            except queue.Empty:
                break
            if job is not None:
                job.abandoned = True
                _cancel_soon(job)
        jobs.put(None)


def _cancel_soon(job: _Job[Any]) -> None:
    with contextlib.suppress(RuntimeError):  # a closed loop: nobody waits any more
        job.loop.call_soon_threadsafe(job.fut.cancel)
