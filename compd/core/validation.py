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
- ``stuck``        the same raw value while the machine moves around it, by
  either of two criteria:

  * time: unchanged for longer than ``stuck_after_s`` while other channels
    move, counted from the later of its last change and the first move of
    another channel after it (a machine at rest overnight moves nothing: when
    the spindle starts, a sensor still has ``stuck_after_s`` to follow). A
    quantised 0.1 K sensor heating at 0.5 K/h changes every 12 min: it is not
    stuck if ``stuck_after_s`` is longer;
  * heat: unchanged while another temperature channel moved by more than
    ``stuck_delta_k`` (by its accepted values) since this one last changed.
    A slow drift moves every sensor a quantum at a time, so this needs no
    long ``stuck_after_s``: over 8 h heating at 0.5 K/h, out of phase, the
    others move at most a quantum or two between two changes of this one,
    while a bearing frozen at the start of a warm-up is flagged as soon as the
    motor or another bearing has risen ``stuck_delta_k`` (minutes). Once
    flagged it stays flagged until the value changes, even if the others cool
    back. Only for sensors that must follow the machine's heat: a hall's
    ambient sensor may rightly stay put while the spindle warms by 10 K.
- ``rate``         it moved away from the last accepted value faster than
  ``max_rate_per_s`` (a one-sample spike; with a relative tolerance of
  ``RATE_RTOL`` for float rounding); the reference is the last ACCEPTED
  value, so a spike never becomes the reference.

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
from dataclasses import dataclass, field

from drivers.base import Quality, Sample

#: relative tolerance of the rate check: 20.1 - 20.0 is 0.10000000000000142
#: in floats, so a limit of exactly one 0.1 K quantum per sample would refuse
#: a genuine step
RATE_RTOL = 1e-9


@dataclass(frozen=True, slots=True)
class ChannelLimits:
    """What a channel's value must satisfy."""

    low: float
    high: float
    max_rate_per_s: float | None = None
    stale_after_s: float | None = None
    stuck_after_s: float | None = None
    #: flagged stuck when unchanged while another temperature channel moved more
    stuck_delta_k: float | None = None
    #: a temperature (degC or K): its moves count for other channels' stuck_delta_k
    temperature: bool = False


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
    #: the other temperature channels' accepted values when this one last changed
    peer_ref: dict[str, float] = field(default_factory=dict)
    #: one of them has since moved more than stuck_delta_k (latched until a change)
    peer_moved: bool = False
    #: when another channel first changed after this one last did
    others_moved_s: float | None = None


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
        accepted: dict[str, float] = {}
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
                accepted[name] = v
        # the heat criterion, against the temperatures accepted in this same cycle
        for name, lim in self.limits.items():
            if (lim.stuck_delta_k is not None and name in accepted
                    and self._peers_moved(name, accepted, lim.stuck_delta_k)):
                out[name] = "stuck"
                del accepted[name]
        for name, v in accepted.items():
            self._tracks[name].good_value = v
            self._tracks[name].good_s = now_s
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
            tr.peer_ref.clear()
            tr.peer_moved = False
            tr.others_moved_s = None

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
        if lim.stuck_after_s is not None and self._stuck(name, tr, lim.stuck_after_s, now_s):
            return "stuck"
        if (lim.max_rate_per_s is not None and tr.good_value is not None
                and tr.good_s is not None):
            dt = now_s - tr.good_s
            allowed = lim.max_rate_per_s * dt * (1.0 + RATE_RTOL)
            if dt <= 0.0 or abs(v - tr.good_value) > allowed:
                return "rate" if v != tr.good_value else None
        return None

    def _stuck(self, name: str, tr: _Track, stuck_after_s: float, now_s: float) -> bool:
        since = tr.last_change_s
        if since is None:
            return False
        if tr.others_moved_s is None:
            # stuck only while others move: from another channel's first change
            # after this one froze
            moved = [other.last_change_s for n, other in self._tracks.items()
                     if n != name and other.last_change_s is not None
                     and other.last_change_s > since]
            if not moved:
                return False
            tr.others_moved_s = min(moved)
        return now_s - tr.others_moved_s > stuck_after_s

    def _peers_moved(self, name: str, accepted: Mapping[str, float], delta_k: float) -> bool:
        """Another temperature channel's accepted value (this cycle's, else its
        last) moved more than `delta_k` since this channel last changed (each
        peer's baseline: its first accepted value after that change)."""
        tr = self._tracks[name]
        if not tr.peer_moved:
            for n, other in self._tracks.items():
                value = accepted.get(n, other.good_value)
                if n == name or value is None or not self.limits[n].temperature:
                    continue
                ref = tr.peer_ref.setdefault(n, value)
                if abs(value - ref) > delta_k:
                    tr.peer_moved = True
                    break
        return tr.peer_moved

    # -- state across restarts ----------------------------------------------------

    def export_state(self) -> dict[str, dict[str, float | None]]:
        return {n: {"good_value": t.good_value} for n, t in self._tracks.items()}
