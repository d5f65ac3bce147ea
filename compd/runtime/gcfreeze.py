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
objects made), so that later collections walk only what was made since.
Freezing is cheap (CPython moves the generation lists whole); counting the
frozen objects is not (`gc.get_freeze_count` walks them: 20 ms for 3 million,
once per machine start; with 512 machines starting in one process it took
55 % of the process's CPU and timed out the running machines' reads), so
nothing here counts them. Objects frozen are still freed by their reference
count; only cyclic garbage alive at that instant stays (a start's worth, once).
"""

from __future__ import annotations

import gc

__all__ = ["freeze_long_lived"]


def freeze_long_lived() -> None:
    """Freeze every object tracked now (see the module doc)."""
    gc.freeze()
