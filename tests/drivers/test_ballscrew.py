"""The ball-screw machine: its error is a line along the travel whose slope the
axis's motion drives (drivers.sim.ballscrew)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from drivers.sim.ballscrew import (
    DEFAULT_POSITIONS_MM,
    constant_program,
    parse_position_column,
    position_column,
    simulate_ballscrew,
)

POSITIONS = (0.0, 150.0, 400.0, 725.5)


def _displacements(cols: dict[str, np.ndarray], positions: tuple[float, ...]) -> np.ndarray:
    return np.column_stack([cols[position_column(x)] for x in positions])


def test_noise_free_displacement_is_exactly_linear_in_position() -> None:
    cols = simulate_ballscrew(12.0, seed=3, positions_mm=POSITIONS, probe_noise_um=0.0)
    d = _displacements(cols, POSITIONS)
    x = np.asarray(POSITIONS)
    expected = cols["value_um"][:, None] + cols["slope_um_m"][:, None] * x[None, :] / 1000.0
    np.testing.assert_allclose(d, expected, rtol=0.0, atol=1e-9)
    # and it moves: both the value and the slope grow well beyond rounding
    assert np.ptp(cols["value_um"]) > 3.0
    assert np.ptp(cols["slope_um_m"]) > 10.0
    assert d[0].tolist() == [0.0] * len(POSITIONS)  # zeroed at rest


def test_slope_grows_with_axis_duty_and_not_with_the_spindle() -> None:
    ends = [simulate_ballscrew(6.0, program=constant_program(0.0, duty, 10_000.0),
                               probe_noise_um=0.0)["slope_um_m"][-1]
            for duty in (0.0, 0.3, 0.6, 0.9)]
    # the same room under each (same seed): the duty alone makes the difference
    assert all(b > a + 5.0 for a, b in itertools.pairwise(ends))
    spindle = simulate_ballscrew(6.0, program=constant_program(10_000.0, 0.0, 0.0),
                                 probe_noise_um=0.0)
    assert abs(spindle["slope_um_m"][-1] - ends[0]) < 1.0
    assert spindle["value_um"][-1] > 5.0  # the spindle moves the value instead


def test_same_seed_same_record_other_seed_other_day() -> None:
    a = simulate_ballscrew(4.0, seed=5)
    b = simulate_ballscrew(4.0, seed=5)
    c = simulate_ballscrew(4.0, seed=6)
    for name in a:
        np.testing.assert_array_equal(a[name], b[name])
    assert not np.array_equal(a["axis_duty"], c["axis_duty"])


def test_position_column_names_round_trip() -> None:
    for x in (*DEFAULT_POSITIONS_MM, -50.0, 12.5):
        assert parse_position_column(position_column(x)) == x
    assert position_column(200.0) == "dx_at_200mm_um"
    assert position_column(1e-5) == position_column(-1e-5) == "dx_at_0mm_um"
    assert position_column(1234.5678) == "dx_at_1234.568mm_um"
    assert position_column(-50.0) == "dx_at_-50mm_um"
    assert parse_position_column("dz_um") is None
    assert parse_position_column("dx_at_mm_um") is None


def test_positions_that_share_a_column_name_are_refused() -> None:
    with pytest.raises(ValueError, match=r"distinct to 0\.001 mm"):
        simulate_ballscrew(1.0, positions_mm=(5.0, 5.0001))
