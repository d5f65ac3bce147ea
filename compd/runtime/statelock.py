"""One daemon per state directory: an exclusive, non-blocking flock on
``state_dir/compd.lock``.

Two daemons on one state directory would interleave checkpoints and records
and fight over the machine's offset, so the second one is refused at once
(never queued). The kernel drops the lock when its holder dies, also on
kill -9, so a crashed daemon never leaves a stale lock behind; the pid written
into the file only serves the error message. The file is never deleted:
unlinking a lock file lets two processes lock two different inodes.

The lock opens the directory once (`compd.runtime.statedir.StateDir`: 0700,
ours, its parents safe from other users) and keeps it open as `directory`:
the lock file, the checkpoint and its temp file are opened relative to that
descriptor, so a path swapped while the daemon runs moves nothing it writes.
The lock file is opened with ``O_NOFOLLOW`` (0600): a link planted at
``compd.lock`` is refused, never followed (it once truncated its target).
"""

from __future__ import annotations

import contextlib
import fcntl
import os
from pathlib import Path
from types import TracebackType

from compd.errors import CompdError
from compd.runtime.statedir import StateDir

__all__ = ["LOCK_NAME", "StateLock", "StateLocked"]

LOCK_NAME = "compd.lock"


class StateLocked(CompdError):
    """Another process holds the state directory. `holder_pid` is None when unknown."""

    def __init__(self, state_dir: Path, holder_pid: int | None) -> None:
        self.state_dir = state_dir
        self.holder_pid = holder_pid
        who = f"pid {holder_pid}" if holder_pid is not None else "an unknown process"
        super().__init__(
            f"state directory {state_dir} is in use by {who} (lock {state_dir / LOCK_NAME}); "
            f"one compd per state directory")


def _read_pid(fd: int) -> int | None:
    try:
        raw = os.pread(fd, 32, 0)
    except OSError:
        return None
    try:
        return int(raw.decode("ascii").strip())
    except (UnicodeDecodeError, ValueError):
        return None


class StateLock:
    """Exclusive lock on a state directory (created if missing)."""

    def __init__(self, state_dir: Path) -> None:
        self.state_dir = Path(state_dir)
        self.path = self.state_dir / LOCK_NAME
        self._fd: int | None = None
        #: the state directory, open while the lock is held
        self.directory: StateDir | None = None

    @property
    def held(self) -> bool:
        return self._fd is not None

    def acquire(self) -> None:
        """Take the lock or raise StateLocked at once. Idempotent while held."""
        if self._fd is not None:
            return
        directory = StateDir.open(self.state_dir)
        try:
            fd = directory.open_file(LOCK_NAME, os.O_RDWR)
        except BaseException:
            directory.close()
            raise
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _read_pid(fd)
            os.close(fd)
            directory.close()
            raise StateLocked(self.state_dir, holder) from None
        except BaseException:
            os.close(fd)
            directory.close()
            raise
        try:
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode("ascii"), 0)
        except OSError:
            pass  # the pid is only for messages; the flock is what counts
        self._fd = fd
        self.directory = directory

    def release(self) -> None:
        """Drop the lock (closing the descriptor releases the flock). Idempotent."""
        fd, self._fd = self._fd, None
        directory, self.directory = self.directory, None
        if fd is None:
            return
        with contextlib.suppress(OSError):
            os.ftruncate(fd, 0)
        os.close(fd)
        if directory is not None:
            directory.close()

    def __enter__(self) -> StateLock:
        self.acquire()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.release()
