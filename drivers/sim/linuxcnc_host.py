"""The machine's one LinuxCNC, for those who start a headless one (the tests, the
benchmarks): the lock every such starter takes, and what tells that a LinuxCNC
somebody else started runs here.

LinuxCNC's HAL is one per machine (System V shared memory), whatever user or
checkout starts it. So the lock is one file for the whole machine, in ``/tmp``
whatever ``TMPDIR`` says (`LOCK_PATH`, readable by every user: ``flock`` needs no
write access), and a starter waits for it as long as another run holds it: a
busy machine makes a run slower, never failed (`host_lock`, bounded only by
`LOCK_WAIT_S`, after which the run is told it is busy: `LinuxCncBusy`).

Holding the lock, a starter that finds a LinuxCNC running (`foreign`: LinuxCNC's
own lock file, its processes, HAL's shared memory) did not start it, and leaves
it alone: `ForeignLinuxCnc`, never ``halrun -U`` (that would stop a shop's
machine, and LinuxCNC's own start script, seeing its lock, would clean the other
instance up by itself when started without a terminal).
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import threading
import time
from collections.abc import Iterator
from pathlib import Path

#: one for the machine, as HAL is (not tempfile.gettempdir(): TMPDIR is per user)
LOCK_PATH = Path("/tmp/compd-linuxcnc.lock")
#: LinuxCNC's own lock file: its start script makes it, its cleanup removes it
LINUXCNC_LOCK = Path("/tmp/linuxcnc.lock")
#: HAL's shared memory key (hal_priv.h HAL_KEY, "HAL2")
HAL_KEY = 0x48414C32
#: LinuxCNC's processes (their /proc/PID/comm)
PROCESSES = frozenset({"rtapi_app", "linuxcncsvr", "milltask", "linuxcnc", "io", "iov2",
                       "halui", "inihal"})
#: how long a starter waits for another run's LinuxCNC: hours, not a test's timeout
LOCK_WAIT_S = 3600.0
#: how often a waiting starter tries the lock again (s)
POLL_S = 0.5


class LinuxCncBusy(RuntimeError):
    """Another run held the machine's LinuxCNC for all of `LOCK_WAIT_S`."""


class ForeignLinuxCnc(RuntimeError):
    """A LinuxCNC this run did not start runs on this machine (the message says
    what shows it)."""


def foreign() -> str | None:
    """What shows a LinuxCNC running here (this process started none: the caller
    holds the lock and runs none), None when nothing does."""
    if LINUXCNC_LOCK.exists():
        return f"LinuxCNC's lock file {LINUXCNC_LOCK} exists"
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        with contextlib.suppress(OSError):
            comm = (proc / "comm").read_text().strip()
            if comm in PROCESSES:
                return f"the LinuxCNC process {comm} (pid {proc.name}) runs"
    with contextlib.suppress(OSError):
        for line in Path("/proc/sysvipc/shm").read_text().splitlines()[1:]:
            key = line.split()[0]
            if key.lstrip("-").isdigit() and int(key) & 0xFFFFFFFF == HAL_KEY:
                return "HAL's shared memory exists (a HAL session is open)"
    return None


class _Held:
    """The lock as this process holds it (re-entrant: a fixture may hold it around
    a test whose controller takes it again)."""

    def __init__(self) -> None:
        self.guard = threading.Lock()
        self.fd: int | None = None
        self.count = 0


_HELD = _Held()


def _open() -> int:
    fd = os.open(LOCK_PATH, os.O_RDONLY | os.O_CREAT, 0o666)
    with contextlib.suppress(OSError):  # another user's file: theirs to set
        os.fchmod(fd, 0o666)
    return fd


def acquire(wait_s: float = LOCK_WAIT_S) -> None:
    """Take the machine's LinuxCNC lock, waiting while another run holds it;
    `LinuxCncBusy` after `wait_s`. Then `ForeignLinuxCnc` (the lock released) when
    a LinuxCNC nobody holding the lock started runs."""
    with _HELD.guard:
        if _HELD.fd is not None:
            _HELD.count += 1
            return
        fd = _open()
        deadline = time.monotonic() + wait_s
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() > deadline:
                    os.close(fd)
                    raise LinuxCncBusy(f"another run held {LOCK_PATH} for {wait_s:g} s "
                                       "(one LinuxCNC per machine)") from None
                time.sleep(POLL_S)
        why = foreign()
        if why is not None:
            os.close(fd)
            raise ForeignLinuxCnc(f"a LinuxCNC this run did not start runs here ({why}): "
                                  "the LinuxCNC tests leave it alone")
        _HELD.fd, _HELD.count = fd, 1


def release() -> None:
    with _HELD.guard:
        if _HELD.fd is None:
            return
        _HELD.count -= 1
        if _HELD.count == 0:
            os.close(_HELD.fd)  # releases the lock
            _HELD.fd = None


@contextlib.contextmanager
def host_lock(wait_s: float = LOCK_WAIT_S) -> Iterator[None]:
    """`acquire` … `release`."""
    acquire(wait_s)
    try:
        yield
    finally:
        release()


__all__ = ["LOCK_PATH", "ForeignLinuxCnc", "LinuxCncBusy", "acquire", "foreign",
           "host_lock", "release"]
