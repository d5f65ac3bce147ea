"""Per-channel input validation (pure: values and the time in, reasons out).

A value is refused when it is:

- ``missing``      the read did not return it (or the whole read failed: ``read_failed``)
- ``bad_quality``  the controller flagged it BAD
- ``not_finite``   NaN or ±inf
- ``out_of_range`` outside the channel's physical range (an open Pt100 reads
  about -200 °C or +850 °C)
- ``stale``        its source timestamp has not advanced for longer than
  ``stale_after_s``, went backwards, or is older than ``stale_after_s``
  against the wall clock (when the caller gives one)
- ``stuck``        the same raw value for longer than ``stuck_after_s`` while
  other channels moved in that time (a quantised 0.1 K sensor heating at
  0.5 K/h changes every 12 min: it is not stuck if ``stuck_after_s`` is longer)
- ``rate``         it moved away from the last accepted value faster than
  ``max_rate_per_s`` (a one-sample spike); the reference is the last
  ACCEPTED value, so a spike never becomes the reference.

Times are machine seconds (monotonic) except the wall-clock age check, which
converts real seconds to machine seconds with ``time_scale``.

Clock steps are not staleness. The wall clock (the caller's) and a source
clock (the controller's, or for protocols without source timestamps the
daemon's own wall clock at the read) are stepped in the field by NTP, an
operator or a daylight-saving change; an hour's step must not hold and then
ramp the compensation away. So:

- the wall clock is followed against the monotonic clock: a step between
  two checks larger than half the smallest ``stale_after_s`` (in real
  seconds) is taken out (slow NTP slewing is followed as it is);
- a source timestamp that goes back by more than that is a clock set back:
  it is taken out of that channel's timestamps, not flagged (a smaller step
  back is an older value: ``stale``); one that jumps forward only makes the
  age smaller. A frozen timestamp is still caught on the monotonic clock.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from drivers.base import Quality, Sample


@dataclass(frozen=True, slots=True)
class ChannelLimits:
    """What a channel's value must satisfy."""

    low: float
    high: float
    max_rate_per_s: float | None = None
    stale_after_s: float | None = None
    stuck_after_s: float | None = None


@dataclass(slots=True)
class _Track:
    last_raw: float | None = None
    last_change_s: float | None = None
    #: last source timestamp, with the clock steps taken out
    last_ts: float | None = None
    last_raw_ts: float | None = None
    ts_step_s: float = 0.0
    last_ts_change_s: float | None = None
    good_value: float | None = None
    good_s: float | None = None


class Validator:
    """Validates one sample set per cycle; remembers what it needs across cycles."""

    def __init__(self, limits: Mapping[str, ChannelLimits], time_scale: float = 1.0) -> None:
        self.limits = dict(limits)
        self.time_scale = time_scale
        self._tracks = {name: _Track() for name in self.limits}
        stale = [lim.stale_after_s for lim in self.limits.values()
                 if lim.stale_after_s is not None]
        #: a clock step larger than this (real seconds) is a step, not an age
        self._step_real_s = 0.5 * min(stale) / time_scale if stale else math.inf
        self._wall_step_s = 0.0
        self._last_wall: tuple[float, float] | None = None  # (now_s, wall without steps)

    def check(self, now_s: float, samples: Mapping[str, Sample] | None,
              wall_s: float | None = None) -> dict[str, str | None]:
        """Reason per channel (None = valid). `samples` None: the read failed."""
        if wall_s is not None:
            wall_s = self._steady_wall(now_s, wall_s)
        if samples is None:
            return dict.fromkeys(self.limits, "read_failed")
        out: dict[str, str | None] = {}
        for name, lim in self.limits.items():
            s = samples.get(name)
            tr = self._tracks[name]
            if s is None:
                out[name] = "missing"
                continue
            v = float(s.value)
            self._note_raw(tr, v, now_s)
            stale = self._note_timestamp(tr, s.timestamp_s, now_s, lim, wall_s)
            reason = self._reason(name, tr, s, v, now_s, lim, stale)
            out[name] = reason
            if reason is None:
                tr.good_value = v
                tr.good_s = now_s
        return out

    # -- internals ------------------------------------------------------------

    def _steady_wall(self, now_s: float, wall_s: float) -> float:
        """The caller's wall clock with its steps taken out (see module doc)."""
        wall = wall_s - self._wall_step_s
        if self._last_wall is not None:
            last_now, last_wall = self._last_wall
            expected = last_wall + (now_s - last_now) / self.time_scale
            if abs(wall - expected) > self._step_real_s:
                self._wall_step_s += wall - expected
                wall = expected
        self._last_wall = (now_s, wall)
        return wall

    @staticmethod
    def _note_raw(tr: _Track, v: float, now_s: float) -> None:
        same = tr.last_raw is not None and (v == tr.last_raw or (
            math.isnan(v) and math.isnan(tr.last_raw)))
        if not same:
            tr.last_raw = v
            tr.last_change_s = now_s

    def _note_timestamp(self, tr: _Track, ts: float, now_s: float, lim: ChannelLimits,
                        wall_s: float | None) -> bool:
        if lim.stale_after_s is None:
            tr.last_ts = ts
            return False
        changed = tr.last_raw_ts is None or ts != tr.last_raw_ts
        tr.last_raw_ts = ts
        ts += tr.ts_step_s
        if tr.last_ts is not None and tr.last_ts - ts > self._step_real_s:
            # the source clock was set back: not an old value
            tr.ts_step_s += tr.last_ts - ts
            ts = tr.last_ts
        backwards = tr.last_ts is not None and ts < tr.last_ts
        if changed:
            tr.last_ts_change_s = now_s
        tr.last_ts = ts
        frozen = (tr.last_ts_change_s is not None
                  and now_s - tr.last_ts_change_s > lim.stale_after_s)
        old = wall_s is not None and (wall_s - ts) * self.time_scale > lim.stale_after_s
        return backwards or frozen or old

    def _reason(self, name: str, tr: _Track, s: Sample, v: float, now_s: float,
                lim: ChannelLimits, stale: bool) -> str | None:
        if s.quality is Quality.BAD:
            return "bad_quality"
        if not math.isfinite(v):
            return "not_finite"
        if not lim.low <= v <= lim.high:
            return "out_of_range"
        if stale:
            return "stale"
        if lim.stuck_after_s is not None and self._stuck(name, tr, now_s, lim.stuck_after_s):
            return "stuck"
        if (lim.max_rate_per_s is not None and tr.good_value is not None
                and tr.good_s is not None):
            dt = now_s - tr.good_s
            if dt <= 0.0 or abs(v - tr.good_value) > lim.max_rate_per_s * dt:
                return "rate" if v != tr.good_value else None
        return None

    def _stuck(self, name: str, tr: _Track, now_s: float, stuck_after_s: float) -> bool:
        since = tr.last_change_s
        if since is None or now_s - since <= stuck_after_s:
            return False
        # stuck only while others move: another channel changed after this one froze
        return any(other.last_change_s is not None and other.last_change_s > since
                   for n, other in self._tracks.items() if n != name)

    # -- state across restarts ----------------------------------------------------

    def export_state(self) -> dict[str, dict[str, float | None]]:
        return {n: {"good_value": t.good_value} for n, t in self._tracks.items()}
