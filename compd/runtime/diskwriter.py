"""A thread per process (by default) for the daemon's blocking disk work, each
machine's in the order given.

A checkpoint save (write, two fsyncs: 0.9-1.5 ms on an idle disk, 18 ms median
on a busy one) and a recorder commit (0.4-0.5 ms) ran on the event loop's
thread, where in `compd run DIR` every machine's cycle waits for them.
`DiskWriter.submit` hands such a job to one of `THREADS` worker threads,
chosen by the job's `key` (the machine's state directory): one machine's jobs
always go to the same thread, so they run one at a time, first in, first out.
It returns the job's future: the caller awaits it (`asyncio.wrap_future`) or
waits on it where it must know the job is done. The threads spend their time
in fsync and SQLite's own code, both of which release the GIL; the Python work
(encoding a checkpoint, formatting a recorder row) stays with the caller.

One thread, not several: on an idle 2-core PC with 768 and 1,024 Modbus
machines in one loop (`benchmarks/bench_daemon_fleet.py`, FLEET_ABLATE
compares), four threads cost the loop more than they saved: every job's
hand-over and every GIL release woke another thread that competed with the
loop for the interpreter (768 machines: p99 lateness 11.8 ms with four
threads, 4.6 ms with one; 1,024: 238 against 52 ms, daemon CPU 1.02 against
0.90 s/s). The disk is one device either way.

The executors are made at the first job and made again in a child process
(a fork does not copy the threads). Python joins the threads at exit, so
every job handed over before the interpreter ends runs to its end.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import TypeVar

__all__ = ["PROCESS_DISK", "THREADS", "DiskWriter"]

#: worker threads per process (each machine's jobs on one of them; see above)
THREADS = 1

T = TypeVar("T")


class DiskWriter:
    """Blocking jobs on a few worker threads, in order per key (see the module doc)."""

    def __init__(self, name: str = "compd-disk", threads: int = THREADS) -> None:
        if threads < 1:
            raise ValueError("threads must be at least 1")
        self._name = name
        self._threads = threads
        self._lock = threading.Lock()
        self._executors: list[ThreadPoolExecutor] = []
        self._pid = 0

    def _pool(self) -> list[ThreadPoolExecutor]:
        with self._lock:
            if not self._executors or self._pid != os.getpid():
                self._executors = [
                    ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"{self._name}-{k}")
                    for k in range(self._threads)]
                self._pid = os.getpid()
            return self._executors

    def submit(self, job: Callable[[], T], key: str = "") -> Future[T]:
        """Run `job` after every job submitted before it with the same `key`; its future."""
        pool = self._pool()
        return pool[hash(key) % len(pool)].submit(job)

    def drain(self) -> None:
        """Wait until every job handed over so far has run (a barrier)."""
        with self._lock:
            pool = list(self._executors) if self._pid == os.getpid() else []
        for future in [executor.submit(lambda: None) for executor in pool]:
            future.result()

    def shutdown(self) -> None:
        """Wait for every job handed over, and end the threads (a new job starts others)."""
        with self._lock:
            pool, self._executors = self._executors, []
        for executor in pool:
            executor.shutdown(wait=True)


#: the process's writer: every machine's checkpoints and recorder commits
PROCESS_DISK = DiskWriter()
