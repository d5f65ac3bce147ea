"""Linearity, superposition of terms and time invariance on random stable filters."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from models.compensation import CompensationModel, Term
from models.tf import TransferFunction


@st.composite
def stable_filters(draw: st.DrawFn) -> tuple[list[float], list[float]]:
    """A random stable filter built from poles inside the unit circle."""
    order = draw(st.integers(1, 4))
    radii = draw(st.lists(st.floats(0.0, 0.995), min_size=order, max_size=order))
    signs = draw(st.lists(st.sampled_from([-1.0, 1.0]), min_size=order, max_size=order))
    den = np.poly([r * s for r, s in zip(radii, signs, strict=True)])
    num = draw(st.lists(st.floats(-5, 5), min_size=1, max_size=order + 1))
    if all(c == 0 for c in num):
        num[0] = 1.0
    return [float(c) for c in num], [float(c) for c in den]


signals = st.lists(st.floats(-50, 50), min_size=1, max_size=60)


@settings(max_examples=60, deadline=None)
@given(stable_filters(), signals, signals, st.floats(-10, 10))
def test_linearity(f: tuple[list[float], list[float]], u: list[float], v: list[float],
                   k: float) -> None:
    n = min(len(u), len(v))
    u_arr, v_arr = np.array(u[:n]), np.array(v[:n])

    def run(x: np.ndarray) -> np.ndarray:
        return TransferFunction(*f, name="p").simulate(x)
    combined = run(k * u_arr + v_arr)
    separate = k * run(u_arr) + run(v_arr)
    scale = 1.0 + float(np.max(np.abs(separate)))
    np.testing.assert_allclose(combined, separate, atol=1e-9 * scale)


@settings(max_examples=60, deadline=None)
@given(stable_filters(), signals, st.integers(0, 20))
def test_time_invariance(f: tuple[list[float], list[float]], u: list[float], delay: int) -> None:
    x = np.array(u)
    y = TransferFunction(*f, name="p").simulate(x)
    shifted = TransferFunction(*f, name="p").simulate(np.concatenate([np.zeros(delay), x]))
    np.testing.assert_allclose(shifted[delay:], y, rtol=1e-12, atol=1e-12)
    assert np.all(shifted[:delay] == 0.0)


@settings(max_examples=40, deadline=None)
@given(stable_filters(), stable_filters(), signals, st.floats(-3, 3))
def test_superposition_of_terms(f1: tuple[list[float], list[float]],
                                f2: tuple[list[float], list[float]], u: list[float],
                                gain: float) -> None:
    a = [20.0 + x for x in u]
    b = [18.0 - 0.5 * x for x in u]
    model = CompensationModel([
        Term("one", {"a": 1.0, "b": -1.0}, TransferFunction(*f1, name="one")),
        Term("two", {"b": 1.0}, TransferFunction(*f2, name="two"), gain=gain),
    ], period_s=1.0)
    model.set_references({"a": 20.0, "b": 18.0})
    total = np.array([model.step({"a": x, "b": y}) for x, y in zip(a, b, strict=True)])
    one = TransferFunction(*f1, name="one").simulate(np.array(a) - 20.0 - (np.array(b) - 18.0))
    two = gain * TransferFunction(*f2, name="two").simulate(np.array(b) - 18.0)
    scale = 1.0 + float(np.max(np.abs(one)) + np.max(np.abs(two)))
    np.testing.assert_allclose(total, one + two, atol=1e-9 * scale)
