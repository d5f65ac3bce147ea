"""Memory the daemon holds stays bounded however long it runs.

- The recorder's SQLite connection keeps a small page cache: SQLite's own
  allocation counter (``sqlite3_memory_used``, read through ctypes from the
  library the ``sqlite3`` module is linked to) grows by far less than SQLite's
  default 2 MB cache after thousands of appended rows.
- glibc's mmap threshold is pinned (`compd.runtime.heap`): a buffer of asyncio's
  socket read size (256 KiB, allocated for every controller response) is a
  mapping of its own, not carved out of the brk heap where it fragments.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

from compd.runtime.heap import pin_mmap_threshold
from compd.runtime.recorder import CACHE_KIB, Recorder, RecordRow


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
                                               "spindle_rpm", "power_kw")}
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


_PROBE = """
import ctypes, sys
from compd.runtime.heap import pin_mmap_threshold

class MallInfo2(ctypes.Structure):
    _fields_ = [(n, ctypes.c_size_t) for n in ("arena", "ordblks", "smblks", "hblks", "hblkhd",
                "usmblks", "fsmblks", "uordblks", "fordblks", "keepcost")]

try:
    info = ctypes.CDLL(None).mallinfo2
except (OSError, AttributeError):
    print("no-mallinfo2")
    sys.exit(0)
info.restype = MallInfo2
startup = bytearray(4 * 1024 * 1024)  # a large mapped block freed, as at startup:
del startup                           # glibc's dynamic threshold rises to 4 MiB
pinned = sys.argv[1] == "pin" and pin_mmap_threshold()
before = info().hblkhd
buffer = bytes(256 * 1024)  # asyncio's socket read size, allocated per response
print(pinned, info().hblkhd - before)
"""


def _mapped_growth(mode: str) -> tuple[bool, int]:
    """In a fresh interpreter: (pinned, bytes glibc mapped for one 256 KiB buffer)."""
    env = {k: v for k, v in os.environ.items()
           if k != "MALLOC_MMAP_THRESHOLD_" and not k.startswith("GLIBC_TUNABLES")}
    out = subprocess.run([sys.executable, "-c", _PROBE, mode], check=True, capture_output=True,
                         text=True, timeout=60, env=env).stdout.split()
    if out == ["no-mallinfo2"]:
        pytest.skip("not glibc >= 2.33 (no mallinfo2)")
    return out[0] == "True", int(out[1])


def test_large_buffers_are_mappings_after_pinning() -> None:
    pinned, mapped = _mapped_growth("pin")
    assert pinned
    assert mapped >= 256 * 1024
    # the mechanism: left dynamic, the same buffer comes from the brk heap
    assert _mapped_growth("no-pin") == (False, 0)


def test_operator_tuning_is_left_alone(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("MALLOC_MMAP_THRESHOLD_", "65536")
    assert not pin_mmap_threshold()
    monkeypatch.delenv("MALLOC_MMAP_THRESHOLD_")
    monkeypatch.setenv("GLIBC_TUNABLES", "glibc.malloc.mmap_threshold=65536")
    assert not pin_mmap_threshold()
