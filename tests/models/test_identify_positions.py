"""Value and slope from displacements at several positions
(models.identify.positions)."""

from __future__ import annotations

import numpy as np
import pytest

from models.identify.positions import fit_value_slope, line_per_sample, predict_at


def test_line_per_sample_worked_example() -> None:
    value, slope = line_per_sample((0.0, 500.0, 1000.0), np.array([[2.0, 7.0, 12.0]]))
    assert value.tolist() == pytest.approx([2.0])
    assert slope.tolist() == pytest.approx([10.0])


def test_line_per_sample_recovers_known_value_and_slope_about_a_reference() -> None:
    rng = np.random.default_rng(0)
    a = rng.normal(0.0, 10.0, 200)
    b = rng.normal(0.0, 40.0, 200)
    x = (100.0, 300.0, 450.0, 900.0)
    x0 = 250.0
    d = a[:, None] + b[:, None] * (np.asarray(x)[None, :] - x0) / 1000.0
    value, slope = line_per_sample(x, d, x0)
    np.testing.assert_allclose(value, a, atol=1e-9)
    np.testing.assert_allclose(slope, b, atol=1e-9)


@pytest.mark.parametrize("positions", [(100.0,), (100.0, 100.0)])
def test_line_needs_two_distinct_positions(positions: tuple[float, ...]) -> None:
    with pytest.raises(ValueError, match="two or more distinct positions"):
        line_per_sample(positions, np.zeros((5, len(positions))))


def _first_order(u: np.ndarray, gain: float, pole: float) -> np.ndarray:
    y = np.zeros_like(u)
    for k in range(1, u.size):
        y[k] = pole * y[k - 1] + gain * (1.0 - pole) * u[k - 1]
    return y


def test_value_and_slope_models_recover_known_gains_from_their_own_inputs() -> None:
    rng = np.random.default_rng(1)
    n = 600
    steps = np.repeat(rng.uniform(0.0, 5.0, n // 20), 20)
    room = np.repeat(rng.uniform(-1.0, 1.0, n // 30), 30)
    steps[:20] = room[:30] = 0.0  # the record starts at rest, the models' zero
    columns = {"nut": 20.0 + steps, "column": 20.0 + room}
    a = _first_order(room, 3.0, 0.9)   # 3 µm/K of the column
    b = _first_order(steps, 11.5, 0.8)  # 11.5 µm/m/K of the screw
    x = (0.0, 200.0, 400.0, 600.0, 800.0)
    d = a[:, None] + b[:, None] * np.asarray(x)[None, :] / 1000.0
    fit = fit_value_slope(x, d, columns, value_inputs=("column",), slope_inputs=("nut",))
    assert sum(fit.value.nums[0]) / sum(fit.value.den) == pytest.approx(3.0, rel=1e-6)
    assert sum(fit.slope.nums[0]) / sum(fit.slope.den) == pytest.approx(11.5, rel=1e-6)
    np.testing.assert_allclose(predict_at(fit, columns, x), d, atol=1e-6)


def test_a_missing_input_is_named() -> None:
    x = (0.0, 500.0)
    with pytest.raises(ValueError, match="nut"):
        fit_value_slope(x, np.zeros((50, 2)), {"column": np.zeros(50)},
                        value_inputs=("column",), slope_inputs=("nut",))
