"""The C heap of a process that runs for months: glibc's mmap threshold, pinned.

glibc serves a malloc of at least the mmap threshold (128 KiB at start) from a
fresh mapping, returned to the system by free. The threshold is dynamic: each
time a mapped block is freed it rises to that block's size (up to 32 MiB), and
startup frees several large ones (files read whole, imports). From then on the
daemon's large short-lived buffers come from the brk heap instead: asyncio's
socket transports allocate ``recv(256 KiB)`` for every response from the
controller (then shrink it to the bytes received), so the heap gets big
blocks carved and returned every cycle, in between SQLite's and Python's
long-lived allocations, and it grows by fragmentation: measured, `compd run`
against the simulated Modbus controller, +1.3 MB of free-but-resident heap
over 14,400 cycles, never levelling off. With the threshold pinned at its
initial 128 KiB (which also stops the dynamic adjustment) those buffers are
mappings again and the heap stays the same size.

`pin_mmap_threshold()` is called once by the daemon. It does nothing on
another C library, nor when the operator tuned the threshold themselves
(``MALLOC_MMAP_THRESHOLD_`` or ``GLIBC_TUNABLES=glibc.malloc.mmap_threshold``).
"""

from __future__ import annotations

import ctypes
import os

__all__ = ["MMAP_THRESHOLD_BYTES", "pin_mmap_threshold"]

#: glibc's own initial threshold (DEFAULT_MMAP_THRESHOLD_MIN)
MMAP_THRESHOLD_BYTES = 128 * 1024
#: mallopt parameter number, from glibc's <malloc.h>
_M_MMAP_THRESHOLD = -3


def _glibc() -> bool:
    try:
        return os.confstr("CS_GNU_LIBC_VERSION") is not None
    except (ValueError, OSError):  # not glibc: the name is unknown
        return False


def _tuned_by_operator() -> bool:
    return ("MALLOC_MMAP_THRESHOLD_" in os.environ
            or "glibc.malloc.mmap_threshold" in os.environ.get("GLIBC_TUNABLES", ""))


def pin_mmap_threshold() -> bool:
    """Fix glibc's mmap threshold at `MMAP_THRESHOLD_BYTES` (see module doc).
    Returns True when it was set; False on another C library, when the
    environment already sets it, or when mallopt refused."""
    if not _glibc() or _tuned_by_operator():
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES))
