"""A failed sensor: the fallback model on the remaining inputs takes over at the
first invalid sample, without a step (the output stage ramps the difference at
the slew limit), in a "degraded" state that is not an alarm, and the main
model is back, ramped, when the sensor returns (`compd.core.fallback`), on the
fake clock."""

from __future__ import annotations

import math

from compd.core.cycle import Cycle
from compd.core.health import Cause
from compd.core.output import Status
from compd.core.plan import Row
from compd.testing import FakeClock
from models.compensation import CompensationModel
from tests.compd.core.cycle_helpers import HOLD_S, SLEW_UM_S, params, samples
from tests.compd.core.fallback_helpers import sp2_with_fallbacks


def _step(cycle: Cycle, clock: FakeClock, bearing: float, ambient: float = 20.0) -> Row:
    t = clock.tick()
    cycle.plan(t, samples(t, bearing, ambient))
    return cycle.commit()


def _warm(cycle: Cycle, clock: FakeClock, n: int) -> list[Row]:
    """A spindle heating the bearing 0.005 K a sample, the ambient drifting."""
    return [_step(cycle, clock, 20.0 + 0.005 * k, 20.0 + 0.002 * k) for k in range(n)]


def _names(rows: list[Row]) -> list[str]:
    return [str(e.name) for r in rows for e in r.events]


def _no_step(rows: list[Row], before_um: float) -> None:
    last = before_um
    for r in rows:
        assert r.stage_um is not None
        assert abs(r.stage_um - last) <= SLEW_UM_S * 1.0 + 1e-9
        last = r.stage_um


def test_sensor_lost_degraded_no_step_and_back_to_main_ramped() -> None:
    cycle, clock = Cycle(params(), sp2_with_fallbacks()), FakeClock()
    warm = _warm(cycle, clock, 200)
    assert warm[-1].cause is Cause.IN_FORCE
    before = warm[-1].stage_um
    assert before is not None and before > 5.0
    lost = [_step(cycle, clock, 21.0 + 0.005 * k, math.nan) for k in range(int(HOLD_S) * 3)]
    assert {r.cause for r in lost} == {Cause.DEGRADED}
    assert all(r.healthy and r.in_force for r in lost)  # degraded is compensating
    assert all(r.status & Status.ALARM == 0 for r in lost)
    assert all(r.status & Status.HOLDING == 0 for r in lost)
    assert "fallback_in_force" in _names(lost[:1])  # at the first invalid sample
    assert not {"fault_hold", "fault_ramp_to_zero"} & set(_names(lost))
    assert all(r.snapshot.fallback_for == "ambient" for r in lost)
    assert all("fallback_total" in r.contributions for r in lost)
    _no_step(lost, before)
    # the fallback, not the frozen main model, drives the output: it kept tracking
    assert lost[-1].model_um is not None and lost[-1].model_um > before + 5.0
    back = [_step(cycle, clock, 21.9, 20.4) for _ in range(120)]
    assert "fallback_ended" in _names(back[:1])
    assert back[0].snapshot.fallback_for is None
    assert {r.cause for r in back[-10:]} == {Cause.IN_FORCE}
    _no_step(back, lost[-1].stage_um or 0.0)


def test_the_fallback_is_warm_stepped_from_the_start() -> None:
    """Its output at the switch is the one of the same fallback stepped on every
    sample since start: no cold start."""
    model = sp2_with_fallbacks()
    cycle, clock = Cycle(params(), model), FakeClock()
    twin = sp2_with_fallbacks().fallbacks["ambient"]
    inputs = [(20.0 + 0.005 * k, 20.0) for k in range(300)]
    for k, (b, a) in enumerate(inputs):
        _step(cycle, clock, b, a)
        if k == 0:
            twin.set_references({"bearing": b})
            twin.reset()
            twin.steady_state({"bearing": b})
        expected = twin.step({"bearing": b})
    row = _step(cycle, clock, 21.5, math.nan)
    assert row.cause is Cause.DEGRADED
    assert row.model_um == expected_next(twin, 21.5)
    assert abs(expected) > 1.0


def expected_next(model: CompensationModel, bearing: float) -> float:
    return model.step({"bearing": bearing})


def test_two_channels_invalid_hold_then_ramp_as_without_fallbacks() -> None:
    cycle, clock = Cycle(params(), sp2_with_fallbacks()), FakeClock()
    _warm(cycle, clock, 100)
    rows = [_step(cycle, clock, math.nan, math.nan) for _ in range(int(HOLD_S) + 2)]
    assert {r.cause for r in rows} == {Cause.INPUTS_INVALID}
    assert "fault_hold" in _names(rows) and "fault_ramp_to_zero" in _names(rows)
    assert "fallback_in_force" not in _names(rows)


def test_degraded_then_a_second_sensor_fails_hold_then_ramp() -> None:
    cycle, clock = Cycle(params(), sp2_with_fallbacks()), FakeClock()
    _warm(cycle, clock, 100)
    one = [_step(cycle, clock, 20.5, math.nan) for _ in range(5)]
    assert {r.cause for r in one} == {Cause.DEGRADED}
    two = [_step(cycle, clock, math.nan, math.nan) for _ in range(3)]
    assert {r.cause for r in two} == {Cause.INPUTS_INVALID}
    ended = [e for r in two for e in r.events if e.name == "fallback_ended"]
    assert len(ended) == 1 and ended[0].fields["now"].startswith("none")


def test_without_a_fallback_for_the_channel_hold_as_before() -> None:
    model = sp2_with_fallbacks()
    del model.fallbacks["ambient"]
    cycle, clock = Cycle(params(), model), FakeClock()
    _warm(cycle, clock, 100)
    rows = [_step(cycle, clock, 20.5, math.nan) for _ in range(3)]
    assert {r.cause for r in rows} == {Cause.INPUTS_INVALID}
    assert "fault_hold" in _names(rows)


def test_a_fallback_that_needs_the_lost_channel_is_never_used() -> None:
    """The file refuses one; built by hand, the cycle holds as without it."""
    model = sp2_with_fallbacks()
    model.fallbacks["ambient"] = sp2_with_fallbacks()  # reads ambient itself
    model.fallbacks["ambient"].fallbacks = {}
    cycle, clock = Cycle(params(), model), FakeClock()
    _warm(cycle, clock, 100)
    rows = [_step(cycle, clock, 20.5, math.nan) for _ in range(3)]
    assert {r.cause for r in rows} == {Cause.INPUTS_INVALID}


def test_a_fresh_checkpoint_keeps_the_fallbacks_state() -> None:
    cycle, clock = Cycle(params(), sp2_with_fallbacks()), FakeClock()
    _warm(cycle, clock, 150)
    state = cycle.export_state()
    assert set(state["fallbacks"]) == {"ambient", "bearing"}
    again = Cycle.from_state(params(), sp2_with_fallbacks(), None, state, fresh=True)
    t = clock.tick()
    a = cycle.plan(t, samples(t, 20.75, math.nan))
    b = again.plan(t, samples(t, 20.75, math.nan))
    assert a.model_um == b.model_um and a.cause is Cause.DEGRADED


def test_rezero_is_relative_for_the_fallback_too() -> None:
    cycle, clock = Cycle(params(), sp2_with_fallbacks()), FakeClock()
    _warm(cycle, clock, 150)
    assert cycle.rezero("test").name == "rezero"
    row = _step(cycle, clock, 20.745, math.nan)  # the inputs as they were: growth ~0
    assert row.cause is Cause.DEGRADED
    assert row.model_um is not None and abs(row.model_um) < 1.0
    assert "fallback_um" in cycle.export_state()["zero"]
