"""An integer offset address whose count is coarse (an int16 at scale 10:
10 µm per count) must not make the offset chatter 1→2→1→2 on consecutive
cycles. The output stage quantises: the count in force changes
only when the wanted (slew-limited) value is a whole count away from it, by
whole counts toward it, never past it; at most one count per cycle when a
count is more than R·Δt, else within R·Δt; always within ±limit_um.

Properties for any count, slew, deadband, limit and target sequence, and the
read-back comparison (half a count) through a loaded config.
"""

from __future__ import annotations

import itertools
import math
import random
from pathlib import Path

from hypothesis import example, given, settings
from hypothesis import strategies as st

from compd.config.loader import load_config
from compd.core.cycle import Cycle, params_from_config
from compd.core.output import OutputStage, Readback, count_warnings
from compd.testing import FakeClock
from drivers.base import Sample
from tests.compd.core.cycle_helpers import params, samples, sp2
from tests.configs import write_config

#: relative slack of the float comparisons (k counts are k·q to a few ulps)
SLACK = 1e-9

MAX_DT_S = 2.0

quanta = st.floats(0.001, 50.0)
slews = st.floats(0.001, 100.0)
dts = st.sampled_from([1.0, 0.0, 0.25, 0.9889, 2.0, 7.0])


def _stage(q: float, slew: float, limit: float, deadband: float,
           initial: float = 0.0) -> OutputStage:
    return OutputStage(limit_um=limit, slew_um_s=slew, deadband_um=deadband,
                       max_dt_s=MAX_DT_S, quantum_um=q, initial_um=initial)


def _run(out: OutputStage, steps: list[tuple[float, float]]
         ) -> tuple[list[float], list[float], list[float]]:
    """Outputs (with the initial one first), clamped targets and slew budgets."""
    ys, targets, budgets = [out.current_um], [], []
    for target, dt in steps:
        ys.append(out.step(target, dt))
        targets.append(max(-out.limit_um, min(out.limit_um, target)))
        budgets.append(out.slew_um_s * min(dt, MAX_DT_S))
    return ys, targets, budgets


@settings(max_examples=300, deadline=None)
@given(quanta, slews, st.floats(0.0, 3.0), st.floats(0.5, 400.0), st.floats(-400.0, 400.0),
       st.lists(st.tuples(st.floats(-500.0, 500.0), dts), max_size=120))
def test_whole_counts_within_the_limit_and_the_slew_budget(
        q: float, slew: float, deadband_counts: float, limit: float, initial: float,
        steps: list[tuple[float, float]]) -> None:
    """Every output is a whole count within ±limit (a start beyond it, compd's
    own offset under a lowered limit, only ever comes in); a cycle moves at
    most one count when a count is more than R·Δt, else at most R·Δt; over
    any window the output moves no more than the slew budget plus two counts
    (on average no faster than R, however coarse the count)."""
    out = _stage(q, slew, limit, deadband_counts * q, initial)
    ys, _, budgets = _run(out, steps)
    for y in ys:
        assert abs(y / q - round(y / q)) < 1e-6, (y, q)
    for a, y in itertools.pairwise(ys):
        assert abs(y) <= max(limit, abs(a))
    for k, (a, b) in enumerate(itertools.pairwise(ys)):
        step, budget = abs(b - a), budgets[k]
        if budget == 0.0:
            assert step == 0.0
        elif budget < q:
            assert step == 0.0 or math.isclose(step, q, rel_tol=1e-6), (a, b, q, budget)
        else:
            assert step <= budget + SLACK * q + 1e-12, (a, b, q, budget)
    for s in range(len(ys)):
        spent = 0.0
        for t in range(s + 1, len(ys)):
            spent += budgets[t - 1]
            assert abs(ys[t] - ys[s]) <= spent + 2.0 * q * (1.0 + 1e-6), (s, t, ys, q)


@settings(max_examples=300, deadline=None)
@given(quanta, slews, st.floats(0.0, 3.0), st.floats(0.5, 400.0), st.floats(-400.0, 400.0),
       st.lists(st.tuples(st.floats(-500.0, 500.0), dts), max_size=120))
def test_a_reversal_needs_the_target_back_by_a_whole_count(
        q: float, slew: float, deadband_counts: float, limit: float, initial: float,
        steps: list[tuple[float, float]]) -> None:
    """The output turns (a move down after a move up, or up after down) only
    when the target has come back more than one count from where the output
    stood, and it never moved up past the highest target seen (down past the
    lowest): no reversal smaller than the hysteresis of one count."""
    out = _stage(q, slew, limit, deadband_counts * q, initial)
    ys, targets, _ = _run(out, steps)
    last = 0  # sign of the last move
    hi = lo = ys[0]
    for k, (a, b) in enumerate(itertools.pairwise(ys)):
        hi, lo = max(hi, targets[k]), min(lo, targets[k])
        move = (b > a) - (b < a)
        if move == 0:
            continue
        assert b <= hi + SLACK * q if move > 0 else b >= lo - SLACK * q, (a, b, hi, lo)
        if move == -last:  # a reversal
            if move < 0:
                assert targets[k] <= a - q * (1.0 - 1e-6), (k, a, b, targets[k], q)
            else:
                assert targets[k] >= a + q * (1.0 - 1e-6), (k, a, b, targets[k], q)
        last = move


@settings(max_examples=300, deadline=None)
@given(quanta, slews, st.floats(0.0, 3.0), st.floats(-300.0, 300.0),
       st.floats(-400.0, 400.0), st.lists(st.tuples(st.floats(0.0, 0.999), dts), max_size=120))
def test_a_target_wobbling_within_one_count_never_turns_the_output(
        q: float, slew: float, deadband_counts: float, base: float, initial: float,
        wobble: list[tuple[float, float]]) -> None:
    """The chatter of the issue: a target that stays within one count (model
    noise across a rounding threshold, at any phase of the grid) moves the
    output one way only, whatever the output started from."""
    limit = 400.0
    out = _stage(q, slew, limit, deadband_counts * q, initial)
    ys, _, _ = _run(out, [(base + f * q, dt) for f, dt in wobble])
    moves = {(b > a) - (b < a) for a, b in itertools.pairwise(ys)} - {0}
    assert len(moves) <= 1, (ys, q, base)


@settings(max_examples=200, deadline=None)
@given(quanta, st.floats(0.05, 100.0), st.floats(0.5, 400.0), st.floats(-400.0, 400.0),
       st.floats(-500.0, 500.0), st.booleans())
@example(q=0.001, slew=1.0, limit=273.15, initial=0.0, target=274.0, on_grid=True)
def test_a_steady_target_is_reached_within_one_count(
        q: float, slew: float, limit: float, initial: float, target: float,
        on_grid: bool) -> None:
    """Given time, the output comes within one count of a steady target, and
    exactly onto it when the target is a whole count (a ramp to 0 ends at 0)."""
    out = _stage(q, slew, limit, 0.0, initial)
    goal = max(-limit, min(limit, target))
    if on_grid:
        goal = math.trunc(goal / q) * q
        if abs(goal) > limit:  # a whole count past the limit by rounding (273150 × 0.001)
            goal -= math.copysign(q, goal)  # the clamp wins: the count just inside it
    # R·Δt a cycle, or at least half of it in whole counts (one when a count is more)
    cycles = math.ceil(2.0 * (abs(goal - out.current_um) + q) / slew) + 10
    y = out.current_um
    for _ in range(cycles):
        y = out.step(goal, 1.0)
    assert abs(y - goal) < q * (1.0 + 1e-6), (y, goal, q)
    if on_grid:
        assert math.isclose(y, goal, rel_tol=1e-9, abs_tol=1e-9 * q), (y, goal)
    assert not out.slewing


def test_the_issue_chatter_on_the_pure_cycle() -> None:
    """10 µm counts, slew 1 µm/s, the sp2 model on a bearing drifting 2 K in
    4000 s with a noisy 0.1 K sensor: never a count up and down on
    consecutive cycles, and the largest step one count. (Main: 45 such
    reversals in 113 moves.)"""
    p = params(offset_quantum_um=10.0, slew_um_s=1.0)
    cycle, clock = Cycle(p, sp2()), FakeClock()
    rng = random.Random(1)
    ys = []
    for k in range(4000):
        t = clock.tick()
        bearing = round(20.0 + 2.0 * k / 4000 + rng.gauss(0.0, 0.03), 1)
        ys.append(cycle.plan(t, samples(t, bearing)).stage_um)
        cycle.commit()
    moves = [(k, b - a) for k, (a, b) in enumerate(itertools.pairwise(ys)) if b != a]
    flips = [(i, j) for (i, a), (j, b) in itertools.pairwise(moves) if a * b < 0]
    assert moves and not flips, flips
    assert max(abs(d) for _, d in moves) == 10.0
    assert ys[-1] >= 20.0


# -- read-back: half a count --------------------------------------------------------


def _coarse_config(tmp_path: Path, slew: float = 1.0) -> Cycle:
    offset = {"unit": 1, "kind": "holding", "address": 20, "type": "int16", "scale": 10.0}
    cfg = load_config(write_config(tmp_path, base="minimal", offset=offset, slew_um_s=slew,
                                   extra=f'[state]\ndir = "{tmp_path / "state"}"\n'))
    assert cfg.offset_quantum_um == 10.0
    return Cycle(params_from_config(cfg), sp2(), offset_um=20.0)


def _at(t: float) -> dict[str, Sample]:
    return {"bearing": Sample(20.0, t), "ambient": Sample(20.0, t)}


def test_readback_of_the_count_in_force_is_no_mismatch(tmp_path: Path) -> None:
    """The int16 ×10 register read back as the count written (and to a hair,
    as a float conversion may give it) is the offset in force."""
    cycle, clock = _coarse_config(tmp_path), FakeClock()
    for readback in (20.0, 20.000000000000004, 19.999999999999996, 24.9):
        t = clock.tick()
        cycle.plan(t, _at(t), readback)
        r = cycle.commit()
        assert "readback_mismatch" not in [e.name for e in r.events], readback
        assert cycle.output.confirmed_um == 20.0


def test_a_foreign_count_is_a_mismatch(tmp_path: Path) -> None:
    """One count (10 µm) other than the count compd wrote is a foreign write:
    the alarm, and the output ramps from it. (Main took anything within
    1.01 counts for the offset in force: a foreign 30 µm went unnoticed.)"""
    cycle, clock = _coarse_config(tmp_path), FakeClock()
    t = clock.tick()
    cycle.plan(t, _at(t), 20.0)
    cycle.commit()
    t = clock.tick()
    r = cycle.plan(t, _at(t), 30.0)
    assert "readback_mismatch" in [e.name for e in r.events]
    assert cycle.output.confirmed_um == 30.0


def test_stage_readback_tolerance_is_half_a_count() -> None:
    out = OutputStage(limit_um=100.0, slew_um_s=1.0, quantum_um=10.0, initial_um=20.0)
    out.confirm()
    assert out.readback_tolerance_um(0.01) == 5.0
    assert out.observe(24.99, 0.01) is Readback.MATCH and out.current_um == 20.0
    assert out.observe(25.01, 0.01) is Readback.FOREIGN and out.current_um == 30.0
    floats = OutputStage(limit_um=100.0, slew_um_s=1.0)
    assert floats.readback_tolerance_um(0.01) == 0.01


def test_counts_snap_and_degenerate_grids() -> None:
    """A start value or a read-back between counts is taken as the nearest
    whole count within the limit; a count beyond the limit leaves only 0; a
    grid finer than any integer type could hold over ±limit is no grid."""
    assert OutputStage(limit_um=100.0, slew_um_s=1.0, quantum_um=10.0,
                       initial_um=16.0).current_um == 20.0
    assert OutputStage(limit_um=95.0, slew_um_s=1.0, quantum_um=10.0,
                       initial_um=95.0).current_um == 90.0
    only_zero = OutputStage(limit_um=5.0, slew_um_s=1.0, quantum_um=10.0)
    assert [only_zero.step(5.0, 1.0) for _ in range(20)] == [0.0] * 20
    assert OutputStage(limit_um=100.0, slew_um_s=1.0, quantum_um=1e-300).quantum_um == 0.0
    assert OutputStage(limit_um=100.0, slew_um_s=1.0, quantum_um=math.inf).quantum_um == 0.0


# -- compd check's warning -----------------------------------------------------------


def test_count_warnings() -> None:
    [w] = count_warnings(quantum_um=10.0, slew_um_s=1.0, period_s=1.0, limit_um=100.0)
    assert "10 µm" in w and "1 µm/s × 1 s = 1 µm" in w and "one count per cycle" in w
    [w] = count_warnings(quantum_um=10.0, slew_um_s=1.0, period_s=1.0, limit_um=5.0)
    assert "only offset it can hold within the limit is 0" in w
    assert count_warnings(quantum_um=0.1, slew_um_s=1.0, period_s=1.0, limit_um=100.0) == []
    assert count_warnings(quantum_um=0.0, slew_um_s=1.0, period_s=1.0, limit_um=100.0) == []
