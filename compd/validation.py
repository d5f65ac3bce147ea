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
    last_ts: float | None = None
    last_ts_change_s: float | None = None
    good_value: float | None = None
    good_s: float | None = None


class Validator:
    """Validates one sample set per cycle; remembers what it needs across cycles."""

    def __init__(self, limits: Mapping[str, ChannelLimits], time_scale: float = 1.0) -> None:
        self.limits = dict(limits)
        self.time_scale = time_scale
        self._tracks = {name: _Track() for name in self.limits}

    def check(self, now_s: float, samples: Mapping[str, Sample] | None,
              wall_s: float | None = None) -> dict[str, str | None]:
        """Reason per channel (None = valid). `samples` None: the read failed."""
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
        backwards = tr.last_ts is not None and ts < tr.last_ts
        if tr.last_ts is None or ts != tr.last_ts:
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
