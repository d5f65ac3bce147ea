"""Memory the daemon holds stays bounded however long it runs.

- The recorder's SQLite connection keeps a small page cache: SQLite's own
  allocation counter (``sqlite3_memory_used``, read through ctypes from the
  library the ``sqlite3`` module is linked to) grows by far less than SQLite's
  default 2 MB cache after thousands of appended rows.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sqlite3
from pathlib import Path

import pytest

from compd.recorder import CACHE_KIB, Recorder, RecordRow


def _sqlite_lib() -> ctypes.CDLL | None:
    """The SQLite library the `sqlite3` module uses, when it is a shared one."""
    name = ctypes.util.find_library("sqlite3")
    if name is None:
        return None
    try:
        lib = ctypes.CDLL(name)
    except OSError:
        return None
    lib.sqlite3_libversion.restype = ctypes.c_char_p
    if lib.sqlite3_libversion().decode() != sqlite3.sqlite_version:
        return None  # another copy (e.g. a statically linked _sqlite3): not its counters
    lib.sqlite3_memory_used.restype = ctypes.c_int64
    return lib


def _row(i: int) -> RecordRow:
    channels = {n: 20.0 + i * 1e-3 for n in ("bearing", "motor", "column", "table", "ambient",
                                               "speed_rpm", "power_kw")}
    return RecordRow(seq=i, mono_s=float(i), wall_s=1e9 + i, offset_um=1.0 + i * 1e-4,
                     model_um=1.0, state="ok", valid=True, channels=channels,
                     validity=dict.fromkeys(channels), contributions={"a": 1.0, "b": 2.0})


def test_recorder_sqlite_memory_stays_within_its_page_cache(tmp_path: Path) -> None:
    lib = _sqlite_lib()
    if lib is None:
        pytest.skip("the SQLite library of the sqlite3 module is not reachable through ctypes")
    rows = 6000  # about 2.4 MB of database: SQLite's default cache would fill with it
    before = lib.sqlite3_memory_used()
    recorder = Recorder(tmp_path / "samples.sqlite", commit_every=10)
    recorder.open()
    try:
        for i in range(rows):
            recorder.record(_row(i))
        held = lib.sqlite3_memory_used() - before
    finally:
        recorder.close()
    assert recorder.committed == rows
    # the page cache (CACHE_KIB) plus SQLite's fixed per-connection share
    assert held < CACHE_KIB * 1024 + 512 * 1024
