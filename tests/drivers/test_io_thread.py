"""IoThread: one worker thread per driver, bounded waits, abandoned jobs skipped."""

from __future__ import annotations

import asyncio
import gc
import threading

import pytest

from drivers.io_thread import IoThread

#: generous bound for a worker to react; tests never assert how fast it is
_SLOW_S = 5.0


async def test_every_call_runs_on_one_thread_that_is_not_the_loop() -> None:
    io = IoThread("t-io")
    try:
        idents = {await io.call(threading.get_ident, _SLOW_S) for _ in range(20)}
        assert len(idents) == 1
        assert threading.get_ident() not in idents
        assert io.thread_ids == frozenset(idents)
        names = {await io.call(lambda: threading.current_thread().name, _SLOW_S)}
        assert names == {"t-io"}
    finally:
        io.shutdown()


async def test_results_and_exceptions_come_back_to_the_caller() -> None:
    io = IoThread("t-io")
    try:
        assert await io.call(lambda: 41 + 1, _SLOW_S) == 42

        def boom() -> None:
            raise KeyError("refused")

        with pytest.raises(KeyError, match="refused"):
            await io.call(boom, _SLOW_S)
        assert await io.call(lambda: "still serving", _SLOW_S) == "still serving"
    finally:
        io.shutdown()


async def test_timeout_frees_the_caller_and_skips_the_jobs_it_abandoned() -> None:
    io = IoThread("t-io")
    release = threading.Event()
    ran: list[str] = []
    try:
        def stuck() -> str:
            release.wait(_SLOW_S)
            ran.append("stuck")
            return "late"

        with pytest.raises(TimeoutError):
            await io.call(stuck, 0.02)
        # queued behind the stuck job, times out before the thread reaches it
        with pytest.raises(TimeoutError):
            await io.call(lambda: ran.append("queued"), 0.02)
        release.set()
        # the thread is usable again once the stuck call returned on its own
        assert await io.call(lambda: "next", _SLOW_S) == "next"
        assert ran == ["stuck"]
    finally:
        release.set()
        io.shutdown()


async def test_a_cancelled_caller_gets_cancelled_and_its_queued_job_is_skipped() -> None:
    io = IoThread("t-io")
    release = threading.Event()
    started = threading.Event()
    ran: list[str] = []
    try:
        def stuck() -> None:
            started.set()
            release.wait(_SLOW_S)

        first = asyncio.create_task(io.call(stuck, _SLOW_S))
        second = asyncio.create_task(io.call(lambda: ran.append("queued"), _SLOW_S))
        await asyncio.to_thread(started.wait, _SLOW_S)
        second.cancel()
        with pytest.raises(asyncio.CancelledError):
            await second
        release.set()
        await first
        assert await io.call(lambda: "next", _SLOW_S) == "next"
        assert ran == []
    finally:
        release.set()
        io.shutdown()


async def test_shutdown_stops_the_thread_and_a_new_call_starts_a_new_one() -> None:
    io = IoThread("t-io")
    thread = await io.call(threading.current_thread, _SLOW_S)
    assert io.alive
    io.shutdown()
    io.shutdown()  # idempotent
    await asyncio.to_thread(thread.join, _SLOW_S)
    assert not thread.is_alive()
    assert not io.alive
    again = await io.call(threading.current_thread, _SLOW_S)
    try:
        assert again is not thread  # (its ident may be reused: the old one ended)
        assert again.is_alive()
    finally:
        io.shutdown()
        await asyncio.to_thread(again.join, _SLOW_S)


async def test_shutdown_cancels_jobs_still_queued() -> None:
    io = IoThread("t-io")
    release = threading.Event()
    started = threading.Event()
    ran: list[str] = []
    try:
        def stuck() -> None:
            started.set()
            release.wait(_SLOW_S)

        first = asyncio.create_task(io.call(stuck, _SLOW_S))
        queued = asyncio.create_task(io.call(lambda: ran.append("queued"), _SLOW_S))
        await asyncio.to_thread(started.wait, _SLOW_S)
        io.shutdown()
        with pytest.raises(asyncio.CancelledError):
            await queued
        release.set()
        await first  # a call already running finishes on its own
        assert ran == []
    finally:
        release.set()


async def test_a_dropped_io_thread_stops_its_worker() -> None:
    io = IoThread("t-io")
    thread = await io.call(threading.current_thread, _SLOW_S)
    del io
    gc.collect()
    await asyncio.to_thread(thread.join, _SLOW_S)
    assert not thread.is_alive()
