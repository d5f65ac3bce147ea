"""The daemon's schedule, sans clock: absolute deadlines, skipped periods on an
overrun, and the budget of a ramp-to-zero shutdown.

The shell reads its monotonic clock and hands the reading in; nothing here
reads a clock or sleeps, so hours of schedule are tested in milliseconds.

- Deadline k is ``start + k * period`` (real seconds), computed from k each
  time rather than summed period by period: after a month of cycles the
  deadlines are where the first one said, with no accumulated rounding.
- `advance(now)` after a cycle moves to the next deadline. A cycle that ends
  past that deadline is an overrun: the schedule skips to the first deadline
  still in the future (on the same grid) and reports how many it skipped,
  so a late cycle is never followed by a burst of catch-up cycles.
- Machine time is real time since the start times ``time_scale`` (a
  simulated machine may run faster than the wall).
- A ramp-to-zero shutdown gets the cycles a full-scale ramp needs at the
  slew limit, plus a margin (`shutdown_ramp_cycles`): it ends when the
  offset reaches zero or when that budget is spent, never later.
"""

from __future__ import annotations

import math

#: cycles granted beyond the full-scale ramp (a slew step that lands short of zero)
SHUTDOWN_MARGIN_CYCLES = 10


class Schedule:
    """Absolute deadlines every `period_s` real seconds from `start_s`."""

    def __init__(self, period_s: float, start_s: float, time_scale: float = 1.0) -> None:
        if not (math.isfinite(period_s) and period_s > 0.0):
            raise ValueError(f"period must be a positive number of seconds, got {period_s!r}")
        self.period_s = period_s
        self.start_s = start_s
        self.time_scale = time_scale
        #: index of the current deadline (0: the start itself)
        self.index = 0
        #: cycles that ended past their next deadline
        self.overruns = 0

    @property
    def deadline_s(self) -> float:
        """The current deadline, on the caller's clock."""
        return self.start_s + self.index * self.period_s

    def machine_s(self, now_s: float) -> float:
        """Machine seconds since the start at clock reading `now_s`."""
        return (now_s - self.start_s) * self.time_scale

    def advance(self, now_s: float) -> int:
        """Move to the next deadline after a cycle that ended at `now_s`.

        Returns 0 when that deadline is still ahead (or exactly now), else the
        number of deadlines skipped: the new deadline is the first one after
        `now_s`, and the overrun is counted.
        """
        self.index += 1
        late_s = now_s - self.deadline_s
        if late_s <= 0.0:
            return 0
        missed = math.floor(late_s / self.period_s) + 1
        self.index += missed
        while self.deadline_s <= now_s:  # floor() of a rounded quotient can land on `now`
            self.index += 1
            missed += 1
        self.overruns += 1
        return missed

    def wait_s(self, now_s: float) -> float:
        """Seconds from `now_s` to the current deadline (negative: already late)."""
        return self.deadline_s - now_s


#: the most cycles a ramp-to-zero shutdown is granted (finite whatever the
#: numbers: a 1e308 µm limit at 1e-10 µm/s was an OverflowError on SIGTERM,
#: and no final checkpoint)
MAX_SHUTDOWN_CYCLES = 10**7


def shutdown_ramp_cycles(limit_um: float, slew_um_s: float, period_s: float) -> int:
    """Cycles granted to a ramp-to-zero shutdown: the full-scale ramp
    (`limit_um` at `slew_um_s`, machine seconds) plus `SHUTDOWN_MARGIN_CYCLES`,
    at most MAX_SHUTDOWN_CYCLES plus the margin."""
    per_cycle = slew_um_s * period_s
    n = abs(limit_um) / per_cycle if per_cycle > 0.0 else math.inf
    ramp = math.ceil(n) if n < MAX_SHUTDOWN_CYCLES else MAX_SHUTDOWN_CYCLES
    return ramp + SHUTDOWN_MARGIN_CYCLES


#: machines of one process start at least this far apart (a daemon's start-up,
#: mostly its recorder's SQLite schema, holds the loop for a few milliseconds)
START_SPACING_S = 0.01


def staggered_starts(n: int, period_s: float,
                     min_spacing_s: float = START_SPACING_S) -> list[float]:
    """Start delays (s) for `n` machines sharing one loop, at a common `period_s`
    (the shortest of their periods).

    Two things at once: the starts are at least `min_spacing_s` apart (a burst
    of start-ups would hold the loop for seconds and time out every running
    machine's reads), and the machines' cycles fall evenly over the period
    (phases k/n of it: started together, every machine's deadline would be the
    same instant, and the last of n would always be late by the others' cycles).
    Spacing the starts by c·period/n with c the smallest integer ≥ n·spacing/period
    coprime with n gives both: the phases k·c/n mod 1 are a permutation of k/n.
    """
    if n <= 0:
        return []
    if not (math.isfinite(period_s) and period_s > 0.0):
        raise ValueError(f"period must be a positive number of seconds, got {period_s!r}")
    c = max(1, math.ceil(n * min_spacing_s / period_s - 1e-9))
    while math.gcd(c, n) != 1:
        c += 1
    step_s = c * period_s / n
    return [k * step_s for k in range(n)]
