"""When the cyclic garbage collector's full collections run: between cycles, rarely.

CPython collects generation 2 (every tracked object not frozen) whenever ten
generation-1 collections have passed and the objects promoted since the last
full collection exceed a quarter of those that survived it. After start-up has
frozen its objects (`compd.runtime.gcfreeze`) the survivors are few, so that
condition holds almost every time: in one process serving 768 Modbus machines
(benchmarks/bench_daemon_fleet.py) full collections of 24-64 ms came every few
seconds, each one inside some machine's cycle and late by as much.

`GcPolicy.install` leaves the young generations' automatic collections as
they are (cheap: they walk only what was made since the last ones) and takes
the full one out of the allocator's hands (a generation-2 threshold no
process reaches); `after_cycle`, called by the loop after a cycle and its
checkpoint, runs the full collection when `full_every_s` have passed and the
cycle's slack to its next deadline is at least `min_slack_s`. One that has
found no such slack for twice the interval runs anyway, so cyclic garbage
stays bounded. The policy is the process's (`PROCESS_GC`): in `compd run DIR`
every machine's loop asks it, and the first to find it due collects, once per
interval for the whole process.
"""

from __future__ import annotations

import gc
import time
from collections.abc import Callable

__all__ = ["FULL_EVERY_S", "MIN_SLACK_S", "PROCESS_GC", "GcPolicy"]

#: seconds between two full collections
FULL_EVERY_S = 60.0
#: the least time to the next deadline in which a full collection is started
MIN_SLACK_S = 0.2
#: a generation-2 threshold no process reaches (one count per generation-1 collection)
NEVER = 2**31 - 1


class GcPolicy:
    """Full collections between cycles, at most once per `full_every_s`."""

    def __init__(self, *, full_every_s: float = FULL_EVERY_S,
                 min_slack_s: float = MIN_SLACK_S,
                 clock: Callable[[], float] = time.monotonic,
                 collect: Callable[[int], object] = gc.collect) -> None:
        if not full_every_s > 0 or min_slack_s < 0:
            raise ValueError("full_every_s must be positive and min_slack_s not negative")
        self.full_every_s = full_every_s
        self.min_slack_s = min_slack_s
        self._clock = clock
        self._collect = collect
        self._last: float | None = None
        self._saved: tuple[int, int, int] | None = None
        self._users = 0
        #: full collections this policy ran
        self.collections = 0

    @property
    def installed(self) -> bool:
        return self._saved is not None

    def install(self) -> None:
        """Take the full collection out of the allocator's hands; every machine of
        the process calls it at its start, and `uninstall` when it ends."""
        self._users += 1
        if self._saved is None:
            self._saved = gc.get_threshold()
            young, middle, _ = self._saved
            gc.set_threshold(young, middle, NEVER)
        if self._last is None:
            self._last = self._clock()

    def uninstall(self) -> None:
        """The last machine ended: CPython's thresholds as they were before `install`."""
        self._users = max(0, self._users - 1)
        if self._users:
            return
        saved, self._saved = self._saved, None
        if saved is not None:
            gc.set_threshold(*saved)

    def after_cycle(self, slack_s: float) -> bool:
        """A cycle ended `slack_s` before its next deadline: collect generation 2
        when due (see the module doc). Whether it collected."""
        if self._saved is None or self._last is None:
            return False
        waited = self._clock() - self._last
        if waited < self.full_every_s:
            return False
        if slack_s < self.min_slack_s and waited < 2.0 * self.full_every_s:
            return False
        self._collect(2)
        self._last = self._clock()
        self.collections += 1
        return True


#: the process's policy (`compd.runtime.daemon.Daemon` installs it at its start)
PROCESS_GC = GcPolicy()
