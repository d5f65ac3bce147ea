"""Stepping, batch simulation, state round trips, steady state, bad models."""

from __future__ import annotations

import math

import numpy as np
import pytest

from models.errors import ModelError
from models.tf import TransferFunction
from tests.models.paper_tfs import PAPER_TFS

NAMES = sorted(PAPER_TFS)


def _input(n: int, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.cumsum(rng.normal(0, 0.05, n)) + np.round(rng.normal(0, 1, n), 1)


@pytest.mark.parametrize("name", NAMES)
def test_stepping_one_by_one_equals_simulate_bit_for_bit(name: str) -> None:
    u = _input(5_000)
    batch = TransferFunction(*PAPER_TFS[name], name=name).simulate(u)
    tf = TransferFunction(*PAPER_TFS[name], name=name)
    stepped = np.array([tf.step(float(x)) for x in u])
    assert np.array_equal(batch, stepped)


@pytest.mark.parametrize("name", NAMES)
def test_state_export_import_continues_the_same_sequence_exactly(name: str) -> None:
    u = _input(4_000, seed=2)
    whole = TransferFunction(*PAPER_TFS[name], name=name).simulate(u)
    first = TransferFunction(*PAPER_TFS[name], name=name)
    head = first.simulate(u[:1_500])
    state = first.export_state()
    assert all(isinstance(v, float) for v in state["z"])  # plain lists of floats
    restarted = TransferFunction(*PAPER_TFS[name], name=name)
    restarted.import_state(state)
    tail = restarted.simulate(u[1_500:])
    assert np.array_equal(np.concatenate([head, tail]), whole)


@pytest.mark.parametrize("name", NAMES)
def test_steady_state_gives_constant_output_for_constant_input(name: str) -> None:
    tf = TransferFunction(*PAPER_TFS[name], name=name)
    y0 = tf.steady_state(3.7)
    assert y0 == pytest.approx(tf.dc_gain * 3.7, rel=1e-12)
    y = tf.simulate(np.full(20_000, 3.7))
    np.testing.assert_allclose(y, tf.dc_gain * 3.7, rtol=1e-9)


def test_reset_returns_to_rest() -> None:
    tf = TransferFunction(*PAPER_TFS["eps_SP3"], name="sp3")
    first = tf.simulate(np.ones(10))
    tf.reset()
    assert np.array_equal(tf.simulate(np.ones(10)), first)


@pytest.mark.parametrize(
    ("a", "b", "message"),
    [
        (["1"], [], "denominator is empty"),
        ([], ["1"], "numerator is empty"),
        (["1", "0.5"], ["0", "1"], "b0 is zero"),
        ([float("nan"), 1.0], [1.0, -0.5], "not finite"),
        ([1.0], [1.0, float("inf")], "not finite"),
        (["1"], ["1", "-1.5"], "unstable: pole"),
        (["1"], ["1", "-1"], "unstable: pole"),
        (["0", "0"], ["1", "-0.5"], "all zeros"),
        (["abc"], ["1"], "is not a number"),
        ([True], ["1"], "must be a number"),
        (["1"], ["0.5", "1e308"], "does not fit"),
        (["1e308"], ["1e-300", "1e-301"], "does not fit"),
    ],
)
def test_bad_models_are_refused_with_a_clear_message(a: list[object], b: list[object],
                                                     message: str) -> None:
    with pytest.raises(ModelError, match=message) as info:
        TransferFunction(a, b, "term_x")  # type: ignore[arg-type]
    assert "term_x" in str(info.value)


def test_bad_state_is_refused() -> None:
    tf = TransferFunction(*PAPER_TFS["eps1"], name="e1")
    with pytest.raises(ModelError, match="3 values"):
        tf.import_state({"z": [0.0]})
    with pytest.raises(ModelError, match="non-finite"):
        tf.import_state({"z": [0.0, math.nan, 0.0]})


def test_pole_at_minus_one_cancelled_exactly_too() -> None:
    # (1 + z⁻¹)·0.5 / ((1 + z⁻¹)(1 - 0.5 z⁻¹))
    tf = TransferFunction(["0.5", "0.5"], ["1", "0.5", "-0.5"], "alt")
    assert tf.cancelled == [-1]
    assert tf.is_stable and tf.order == 1
    assert tf.dc_gain == pytest.approx(1.0)


def test_near_cancellation_is_not_cancelled() -> None:
    with pytest.raises(ModelError, match="unstable"):
        TransferFunction(["-0.0251", "0.02511"], ["1", "-1.9985", "0.9985"], "near")
