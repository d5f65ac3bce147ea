"""Per-channel validation, one reason at a time."""

from __future__ import annotations

import math

from compd.validation import ChannelLimits, Validator
from drivers.base import Quality, Sample


def _v(**limits: float) -> Validator:
    return Validator({"t": ChannelLimits(-20.0, 150.0, **limits),
                      "other": ChannelLimits(-1e9, 1e9)})


def _s(v: float, ts: float, q: Quality = Quality.GOOD) -> dict[str, Sample]:
    return {"t": Sample(v, ts, q), "other": Sample(ts, ts)}


def test_reasons() -> None:
    v = _v()
    assert v.check(1.0, _s(20.0, 1.0))["t"] is None
    assert v.check(2.0, _s(math.nan, 2.0))["t"] == "not_finite"
    assert v.check(3.0, _s(850.0, 3.0))["t"] == "out_of_range"
    assert v.check(4.0, _s(-200.0, 4.0))["t"] == "out_of_range"
    assert v.check(5.0, _s(20.0, 5.0, Quality.BAD))["t"] == "bad_quality"
    assert v.check(6.0, {"other": Sample(1.0, 6.0)})["t"] == "missing"
    assert v.check(7.0, None) == {"t": "read_failed", "other": "read_failed"}
    assert v.check(8.0, _s(20.0, 8.0, Quality.UNCERTAIN))["t"] is None


def test_rate_uses_the_last_accepted_value() -> None:
    v = _v(max_rate_per_s=0.5)
    assert v.check(1.0, _s(20.0, 1.0))["t"] is None
    assert v.check(2.0, _s(70.0, 2.0))["t"] == "rate"  # +50 K spike
    assert v.check(3.0, _s(20.4, 3.0))["t"] is None  # against 20.0 two seconds ago
    assert v.check(4.0, _s(21.0, 4.0))["t"] == "rate"


def test_stale_timestamp_frozen_backwards_and_old() -> None:
    v = _v(stale_after_s=10.0)
    for k in range(1, 13):
        r = v.check(float(k), _s(20.0, 1.0))
    assert r["t"] == "stale"
    v = _v(stale_after_s=10.0)
    v.check(1.0, _s(20.0, 100.0))
    assert v.check(2.0, _s(20.0, 99.0))["t"] == "stale"  # went backwards
    v = Validator({"t": ChannelLimits(-20, 150, stale_after_s=10.0)}, time_scale=10.0)
    # 2 real seconds old at a 10x time scale: 20 machine seconds
    assert v.check(1.0, {"t": Sample(20.0, 100.0)}, wall_s=102.0)["t"] == "stale"
    assert v.check(2.0, {"t": Sample(20.0, 101.5)}, wall_s=102.0)["t"] is None


def test_stuck_needs_other_channels_moving() -> None:
    v = _v(stuck_after_s=100.0)
    for k in range(300):  # everything frozen: a machine at rest is not "stuck"
        r = v.check(float(k), {"t": Sample(20.0, float(k)), "other": Sample(1.0, float(k))})
    assert r["t"] is None
    for k in range(300, 420):  # now the other channel moves
        r = v.check(float(k), {"t": Sample(20.0, float(k)), "other": Sample(k, float(k))})
    assert r["t"] == "stuck"
    r = v.check(421.0, {"t": Sample(20.1, 421.0), "other": Sample(1.0, 421.0)})
    assert r["t"] is None
