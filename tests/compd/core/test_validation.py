"""Per-channel validation, one reason at a time."""

from __future__ import annotations

import math

from compd.core.validation import ChannelLimits, Validator
from drivers.base import Quality, Sample


def _v(**limits: float) -> Validator:
    return Validator({"t": ChannelLimits(-20.0, 150.0, **limits),  # type: ignore[arg-type]
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


def _heat(**bearing: float) -> Validator:
    return Validator({
        "bearing": ChannelLimits(-20.0, 150.0, temperature=True, **bearing),
        "motor": ChannelLimits(-20.0, 150.0, temperature=True),
        "speed": ChannelLimits(0.0, 30000.0)})


def _hs(t: float, bearing: float, motor: float, speed: float = 0.0) -> dict[str, Sample]:
    return {"bearing": Sample(bearing, t), "motor": Sample(motor, t), "speed": Sample(speed, t)}


def test_stuck_when_another_temperature_moved_more_than_delta() -> None:
    v = _heat(stuck_delta_k=2.0)
    reasons = [v.check(float(k), _hs(float(k), 20.0, 20.0 + 0.1 * k))["bearing"]
               for k in range(40)]
    assert reasons[:21] == [None] * 21  # the motor moved 2.0 K: not more than 2 K
    assert reasons[21:] == ["stuck"] * 19  # 2.1 K
    # latched: the motor cooling back does not make a frozen value good again
    assert v.check(40.0, _hs(40.0, 20.0, 20.0))["bearing"] == "stuck"
    # a change clears it, and the motor's baseline starts again from here
    assert v.check(41.0, _hs(41.0, 20.1, 20.0))["bearing"] is None
    assert v.check(42.0, _hs(42.0, 20.1, 22.0))["bearing"] is None
    assert v.check(43.0, _hs(43.0, 20.1, 22.1))["bearing"] == "stuck"


def test_stuck_delta_ignores_non_temperatures_and_refused_values() -> None:
    v = _heat(stuck_delta_k=2.0)
    v.check(0.0, _hs(0.0, 20.0, 20.0))
    # the spindle starts (rpm is no temperature) and the motor's sensor opens (850 °C
    # is refused, never a move): the bearing is not stuck for that
    r = v.check(1.0, {"bearing": Sample(20.0, 1.0), "motor": Sample(850.0, 1.0),
                      "speed": Sample(8000.0, 1.0)})
    assert r == {"bearing": None, "motor": "out_of_range", "speed": None}
    # without stuck_delta_k only the time criterion applies
    v = _heat()
    assert all(v.check(float(k), _hs(float(k), 20.0, 20.0 + 0.1 * k))["bearing"] is None
               for k in range(100))


def test_no_stuck_over_8h_of_slow_quantised_heating_out_of_phase() -> None:
    """All three temperatures heat at 0.5 K/h in 0.1 K quanta (a new value every
    12 min), out of phase; both stuck criteria on: never flagged."""
    limits = {n: ChannelLimits(-20.0, 150.0, temperature=True, stuck_after_s=900.0,
                               stuck_delta_k=2.0) for n in ("bearing", "motor", "ambient")}
    v = Validator(limits)
    phases = {"bearing": 0.0, "motor": 240.0, "ambient": 480.0}
    for k in range(0, 8 * 3600, 5):
        t = float(k)
        r = v.check(t, {n: Sample(round(20.0 + 0.5 * (t + ph) / 3600.0, 1), t)
                        for n, ph in phases.items()})
        assert r == dict.fromkeys(phases), (t, r)


def test_stuck_time_counts_from_when_the_others_start_moving() -> None:
    """A night at rest (nothing moves), then the spindle starts: the bearing has
    stuck_after_s from that start to change, not zero."""
    v = _heat(stuck_after_s=100.0)
    for k in range(1000):
        assert v.check(float(k), _hs(float(k), 20.0, 20.0))["bearing"] is None
    reasons = [v.check(float(k), _hs(float(k), 20.0, 20.0, speed=8000.0))["bearing"]
               for k in range(1000, 1200)]
    assert reasons[:101] == [None] * 101  # 1000 s..1100 s after the speed changed
    assert reasons[101:] == ["stuck"] * 99


def test_rate_limit_of_exactly_one_quantum_per_sample_accepts_one_quantum() -> None:
    """0.1 K per 1 s and a 0.1 K sensor: every genuine one-quantum step passes
    (20.1 - 20.0 = 0.10000000000000142 in floats), two quanta do not."""
    assert 20.1 - 20.0 > 0.1
    v = _v(max_rate_per_s=0.1)
    t = 0.0
    for k in range(-200, 1300):  # -20.0 .. 129.9 °C, up by one quantum a second
        t += 1.0
        assert v.check(t, _s(round(k * 0.1, 1), t))["t"] is None, round(k * 0.1, 1)
    for k in range(1299, -201, -1):  # and down
        t += 1.0
        assert v.check(t, _s(round(k * 0.1, 1), t))["t"] is None, round(k * 0.1, 1)
    assert v.check(t + 1.0, _s(-19.8, t + 1.0))["t"] == "rate"  # two quanta
