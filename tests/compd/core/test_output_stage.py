"""The output stage: clamp, slew, deadband, sign, scale; never NaN."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from compd.core.output import OutputStage, Readback, Status


def test_clamp_slew_and_conversion() -> None:
    out = OutputStage(limit_um=50.0, slew_um_s=2.0, sign=-1, units_per_um=1e-3)
    assert out.step(1000.0, 1.0) == 2.0
    assert out.step(1000.0, 0.5) == 3.0
    assert out.to_controller(3.0) == pytest.approx(-0.003)
    assert out.from_controller(-0.003) == pytest.approx(3.0)
    for _ in range(100):
        out.step(1000.0, 1.0)
    assert out.current_um == 50.0


def test_non_finite_target_holds() -> None:
    out = OutputStage(limit_um=50.0, slew_um_s=2.0, initial_um=10.0)
    assert out.step(math.nan, 1.0) == 10.0
    assert out.step(math.inf, 1.0) == 10.0


def test_deadband_only_when_asked() -> None:
    out = OutputStage(limit_um=50.0, slew_um_s=100.0, deadband_um=0.5)
    assert out.step(0.4, 1.0) == 0.0
    assert out.step(0.4, 1.0, deadband=False) == 0.4


def test_dt_cap_and_revert_adopt() -> None:
    out = OutputStage(limit_um=50.0, slew_um_s=1.0, max_dt_s=2.0)
    assert out.step(40.0, 100.0) == 2.0  # a stalled loop earns no big step
    out.confirm()
    out.step(40.0, 1.0)
    out.revert()
    assert out.current_um == 2.0
    out.adopt(math.nan)
    assert out.current_um == 0.0 and out.confirmed_um == 0.0
    out.adopt(500.0)
    assert out.current_um == 50.0


def test_status_bits_fit_a_signed_16_bit_word() -> None:
    assert all(int(b) < 1 << 15 for b in Status)
    assert len({int(b) for b in Status}) == len(list(Status))


@given(st.lists(st.tuples(st.floats(allow_nan=True, allow_infinity=True),
                          st.floats(min_value=0.0, max_value=10.0)), max_size=200))
def test_never_beyond_limit_or_slew(steps: list[tuple[float, float]]) -> None:
    out = OutputStage(limit_um=20.0, slew_um_s=0.5, deadband_um=0.1, max_dt_s=2.0)
    prev = out.current_um
    for target, dt in steps:
        y = out.step(target, dt)
        assert math.isfinite(y) and abs(y) <= 20.0
        assert abs(y - prev) <= 0.5 * min(dt, 2.0) + 1e-12
        prev = y


@given(st.lists(st.tuples(st.floats(-80.0, 80.0), st.sampled_from([1.0, 0.9889, 0.5, 2.0])),
                min_size=1, max_size=60),
       st.sampled_from([0.1, 0.3, 1.0]))
def test_quantised_output_on_the_grid_and_within_the_slew_limit(
        steps: list[tuple[float, float]], quantum_um: float) -> None:
    """An integer offset address (a FOCAS long of 0.1 µm): every output is a
    multiple of the quantum (what the controller will hold) and moves at most
    R·Δt, or a single quantum when R·Δt is below it; it never exceeds the limit."""
    out = OutputStage(limit_um=50.05, slew_um_s=3.9556, quantum_um=quantum_um)
    prev = out.current_um
    for target, dt in steps:
        x = out.step(target, dt)
        assert abs(x) <= 50.05
        assert abs(x / quantum_um - round(x / quantum_um)) < 1e-6
        assert abs(x - prev) <= max(3.9556 * dt, quantum_um) + 1e-9, (prev, x, dt)
        prev = x


def test_quantised_slewing_follows_the_grid() -> None:
    # was: 12.1042 confirmed, 12.1 held by the controller, 16.0598 written
    out = OutputStage(limit_um=100.0, slew_um_s=4.0, quantum_um=0.1, initial_um=12.1)
    assert out.step(40.0, 0.98889) == pytest.approx(16.0)  # 16.0556 rounds past R·Δt
    slow = OutputStage(limit_um=100.0, slew_um_s=0.04, quantum_um=0.1)
    # a count is written once the wanted value is a whole count on (hysteresis)
    assert [round(slow.step(1.0, 1.0), 6) for _ in range(6)] == [0.0, 0.0, 0.1, 0.1,
                                                                  0.2, 0.2]


# -- a limit lowered below the offset compd wrote (a reload, a restart) -----------------


def test_a_start_beyond_a_lowered_limit_ramps_into_it_at_the_slew_limit() -> None:
    """21.55 µm written, the limit lowered to 20: the stage starts from 21.55
    (not a jump to 20) and comes in at 0.5 µm/s, never further out, then holds
    at the limit; the deadband (larger than what is left) does not stop it."""
    out = OutputStage(limit_um=20.0, slew_um_s=0.5, deadband_um=2.0, initial_um=21.55)
    out.confirm()
    assert out.current_um == 21.55 and out.beyond_limit
    ys = [out.step(25.0, 1.0) for _ in range(6)]
    assert ys == pytest.approx([21.05, 20.55, 20.05, 20.0, 20.0, 20.0])
    assert not out.beyond_limit
    # from below: the same, mirrored
    neg = OutputStage(limit_um=20.0, slew_um_s=0.5, initial_um=-21.0)
    assert [neg.step(-30.0, 1.0) for _ in range(3)] == pytest.approx([-20.5, -20.0, -20.0])


def test_the_value_compd_wrote_beyond_a_lowered_limit_is_its_own_not_foreign() -> None:
    out = OutputStage(limit_um=20.0, slew_um_s=0.5, initial_um=21.55)
    out.confirm()
    # float32 rounding of what was written: still compd's own, it steps from it
    assert out.observe(21.550001, 0.01) is Readback.MATCH and not out.held
    assert out.step(0.0, 1.0) == pytest.approx(21.05)
    out.confirm()
    # another value beyond the limit is foreign: held, nothing written from it
    assert out.observe(21.8, 0.01) is Readback.OUT_OF_RANGE and out.held


def test_a_whole_count_beyond_a_lowered_limit_ramps_in_count_by_count() -> None:
    out = OutputStage(limit_um=20.0, slew_um_s=1.0, quantum_um=1.0, initial_um=23.0)
    assert out.current_um == 23.0
    assert [out.step(20.0, 1.0) for _ in range(4)] == [22.0, 21.0, 20.0, 20.0]
