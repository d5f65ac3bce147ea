"""The cyclic garbage collector kept off the daemon's long-lived objects.

CPython's full (generation 2) collection walks every tracked object: the
daemon's models, configs, drivers, the protocol libraries' and asyncio's
objects. In one process serving hundreds of machines (`compd run DIR`) that
walk stalled the event loop: measured in benchmarks/bench_daemon_fleet.py at
384 Modbus machines (192 per worker), one 42-52 ms pause per worker every
~20 s with the CPUs 90 % idle, every daemon's cycle late by as much (p99
lateness 39 ms, the step failed). `freeze_long_lived` moves every object
alive now into the permanent generation (`gc.freeze`), which collections
skip: called when a daemon has connected, before its first deadline (its
objects made; freezing itself walks the heap, 20 ms for 3 million objects,
which inside the cycle made a deadline late), so that later collections walk
only what was made since. Objects frozen are still
freed by their reference count; only cyclic garbage alive at that instant
stays (a start's worth, once).
"""

from __future__ import annotations

import gc

__all__ = ["freeze_long_lived"]


def freeze_long_lived() -> int:
    """Freeze every object tracked now (see the module doc); returns how many are frozen."""
    gc.freeze()
    return gc.get_freeze_count()
