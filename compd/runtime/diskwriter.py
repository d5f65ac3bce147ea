"""One thread per process for the daemon's blocking disk work, in the order given.

A checkpoint save (write, two fsyncs: 0.9-1.5 ms) and a recorder commit
(0.4-0.5 ms) ran on the event loop's thread, where in `compd run DIR` every
machine's cycle waits for them. `DiskWriter.submit` hands such a job to one
worker thread (`concurrent.futures.ThreadPoolExecutor` with one worker, so
jobs run one at a time, first in, first out, whichever machine gave them)
and returns its future: the caller awaits it (`asyncio.wrap_future`) or waits
on it where it must know the job is done. The thread spends its time in
fsync and SQLite's own code, both of which release the GIL; the Python work
(encoding a checkpoint, formatting a recorder row) stays with the caller.

The executor is made at the first job and made again in a child process
(a fork does not copy the thread). Python joins its thread at exit, so every
job handed over before the interpreter ends runs to its end.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import TypeVar

__all__ = ["PROCESS_DISK", "DiskWriter"]

T = TypeVar("T")


class DiskWriter:
    """Blocking jobs run in order on one worker thread (see the module doc)."""

    def __init__(self, name: str = "compd-disk") -> None:
        self._name = name
        self._lock = threading.Lock()
        self._executor: ThreadPoolExecutor | None = None
        self._pid = 0

    def submit(self, job: Callable[[], T]) -> Future[T]:
        """Run `job` after every job submitted before it; its future."""
        with self._lock:
            if self._executor is None or self._pid != os.getpid():
                self._executor = ThreadPoolExecutor(max_workers=1,
                                                    thread_name_prefix=self._name)
                self._pid = os.getpid()
            return self._executor.submit(job)

    def drain(self) -> None:
        """Wait until every job handed over so far has run (a barrier)."""
        with self._lock:
            executor = self._executor if self._pid == os.getpid() else None
        if executor is not None:
            executor.submit(lambda: None).result()

    def shutdown(self) -> None:
        """Wait for every job handed over, and end the thread (a new job starts another)."""
        with self._lock:
            executor, self._executor = self._executor, None
        if executor is not None:
            executor.shutdown(wait=True)


#: the process's writer: every machine's checkpoints and recorder commits
PROCESS_DISK = DiskWriter()
