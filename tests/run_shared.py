"""Files made once a test run and shared by every xdist worker of it.

A session-scoped fixture is made once per process: under ``-n 4`` a 48 h
record or a fit that several test files read would be made by each worker that
runs one of them. `made_once` makes it once for the run: in a folder beside the
workers' own temporary folders (the run's base folder, new every run), under
an exclusive lock, so a worker that comes second waits for the first to finish
and then reads what it made. Without xdist it is the session's own folder."""

from __future__ import annotations

import fcntl
import os
from collections.abc import Callable
from pathlib import Path

import pytest

#: written last into a made folder: its presence says the folder is complete
_DONE = ".made"


def made_once(tmp_path_factory: pytest.TempPathFactory, name: str,
              make: Callable[[Path], None]) -> Path:
    """The folder `name` of this run, filled by ``make(folder)`` the first time
    any worker asks for it. A `make` that raises leaves no mark: the next worker
    that asks tries again (and fails the same way, in its own test)."""
    base = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        base = base.parent  # the run's folder, whose children are the workers' own
    folder = base / f"shared-{name}"
    with (base / f"shared-{name}.lock").open("a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            if not (folder / _DONE).exists():
                folder.mkdir(exist_ok=True)
                make(folder)
                (folder / _DONE).touch()
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
    return folder
