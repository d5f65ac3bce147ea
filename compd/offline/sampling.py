"""A record's sampling judged: `check_sampling` for a CSV's time column (rising, no gap,
no jitter, a period in models.sanity's range), `recorder_time` for the daemon's recorder
(its cycle numbering, then the period over the cycles). Both refuse with `RecordError`
naming the row; neither repairs."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from compd.offline.record_cells import RecordError
from models.sanity import MAX_PERIOD_S, MIN_PERIOD_S

FloatArray = npt.NDArray[np.float64]

#: a sample interval this far from the record's period (fraction) is jitter
JITTER_TOLERANCE = 0.02
#: an interval longer than this many periods is a gap
GAP_FACTOR = 1.5


def recorder_time(mono_s: FloatArray, cycle: npt.NDArray[np.int64],
                  where: str) -> tuple[FloatArray, float]:
    """The recorder's sample times and period, judged on its cycle numbering.

    A recorder holds one row per cycle, stamped with the machine time the
    cycle started (`mono_s`). At a `time_scale` of 50 a millisecond's lateness
    of the event loop is 50 ms of machine time, so the CSV rule (every
    interval within 10 % of the period) refused the daemon's own record. Here
    the cycle numbers must run on by one (a restart or a lost row is refused
    like a backwards timestamp or a gap), the period is the machine time over
    the cycles (least squares), and no row may lie half a period off its
    cycle's time (a missed deadline). The times are then exactly cycle ×
    period. A last row taken early is the stop request's cycle, off the grid:
    it is left out (the other columns are cut to match by the caller)."""
    dt = np.diff(mono_s)
    back = np.flatnonzero(dt <= 0.0)
    if cycle.size == 0 or np.any(cycle < 0) or back.size:  # no numbering, or a restart
        return mono_s - mono_s[0], check_sampling(mono_s, where)
    if dt.size > 2 and dt[-1] < 0.5 * float(np.median(dt)):
        # a stop request runs the last cycle at once, off the sampling grid: not a sample
        # of the record (the rows before it are)
        mono_s, cycle = mono_s[:-1], cycle[:-1]
    step = np.diff(cycle)
    bad = np.flatnonzero(step != 1)
    if bad.size:
        i = int(bad[0])
        kind = "cycle numbers go backwards (a restart)" if step[i] <= 0 else \
            f"{int(step[i]) - 1} cycle(s) missing (a gap)"
        raise RecordError(f"{where}: row {i + 3}: {kind}: cycle {int(cycle[i + 1])} after "
                          f"{int(cycle[i])}; {bad.size} such row(s) in all; split the record "
                          "there")
    k = (cycle - cycle[0]).astype(np.float64)
    y = mono_s - mono_s[0]
    period = float(np.dot(k, y) / np.dot(k, k))  # least squares over every row
    late = np.flatnonzero(np.abs(y - period * k) > 0.5 * period)
    if late.size:
        i = int(late[0])
        raise RecordError(f"{where}: row {i + 2}: cycle {int(cycle[i])} ran at machine time "
                          f"{mono_s[i] - mono_s[0]:g} s, not near {period * k[i]:g} s (a missed "
                          f"deadline; {late.size} such row(s) in all); split the record there")
    period = _nice_period(period)
    return period * k, period


def _nice_period(period: float) -> float:
    """The config's period behind an estimate: 1.0000213 s over the cycles is
    1 s (the fewest significant digits within 0.5 %), or the estimate as it is."""
    for digits in range(1, 7):
        nice = float(f"{period:.{digits}g}")
        if abs(nice - period) <= 5e-3 * period:
            return nice
    return round(period, 9)


def check_sampling(t: FloatArray, where: str) -> float:
    """The record's sample period (the median interval), after checking that
    every interval is that period: no duplicate, backwards step, gap or jitter.
    Rows are reported as file lines (header = line 1)."""
    dt = np.diff(t)
    bad = np.flatnonzero(dt <= 0.0)
    if bad.size:
        i = int(bad[0])
        kind = "duplicated timestamp" if dt[i] == 0.0 else "timestamp goes backwards"
        raise RecordError(f"{where}: row {i + 3}: {kind} ({t[i + 1]!r} after {t[i]!r}); "
                          f"{bad.size} such row(s) in all")
    period_s = float(np.median(dt))
    if not MIN_PERIOD_S <= period_s <= MAX_PERIOD_S:
        raise RecordError(f"{where}: sampled every {period_s:g} s; a calibration record is "
                          f"sampled every {MIN_PERIOD_S:g} … {MAX_PERIOD_S:g} s, as a "
                          "model's period is")
    gaps = np.flatnonzero(dt > GAP_FACTOR * period_s)
    if gaps.size:
        i = int(gaps[0])
        raise RecordError(f"{where}: row {i + 3}: gap of {dt[i]:g} s in a record sampled every "
                          f"{period_s:g} s ({gaps.size} gap(s) in all); split the record "
                          "there instead of resampling")
    jitter = np.flatnonzero(np.abs(dt - period_s) > JITTER_TOLERANCE * period_s)
    if jitter.size:
        i = int(jitter[0])
        raise RecordError(f"{where}: row {i + 3}: non-uniform sampling: interval {dt[i]:g} s "
                          f"where the record's period is {period_s:g} s ({jitter.size} "
                          f"interval(s) off by more than {JITTER_TOLERANCE:.0%})")
    # a period like 1.0000000002 from float timestamps is 1 s
    return float(round(period_s, 9))
