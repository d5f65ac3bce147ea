"""The estimator's numerical domain: no OverflowError or ValueError
comes out of `update`, `refuse` or a restore for any finite input, and a setting
beyond the domain is refused by name, never with an OverflowError later."""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from models.adaptation import DOMAIN, MAX_INPUT_UM, AdaptationParams, Adapter

#: any finite float, the extremes (1e308, subnormals) included
any_finite = st.floats(allow_nan=False, allow_infinity=False)


_POSITIVE = ("probe_noise_um", "gate_sigma", "max_step_um", "max_total_um")


def _setting(name: str) -> st.SearchStrategy[float]:
    """Anywhere in the domain, its edges often."""
    lo, hi = DOMAIN[name]
    low = max(lo, 5e-324) if name in _POSITIVE else lo
    return st.one_of(st.sampled_from([low, hi]), st.floats(low, hi))


params_anywhere = st.builds(
    AdaptationParams,
    gains=st.booleans(),
    **{name: _setting(name) for name in DOMAIN if name != "max_gain"},
    max_gain=st.floats(1e-9, DOMAIN["max_gain"][1]),
)
probe = st.tuples(st.floats(0.0, 1e308), any_finite, any_finite,
                  st.lists(any_finite, min_size=2, max_size=2))


def _finite_state(a: Adapter) -> None:
    s = a.export_state()
    assert all(math.isfinite(v) for v in s["x"] + s["applied"] + [s["pending_s"]])
    assert all(math.isfinite(v) for row in s["P"] for v in row)
    assert math.isfinite(a.bias_sigma_um)


@settings(max_examples=300, deadline=None)
@given(params_anywhere, st.lists(probe, max_size=12))
def test_no_exception_escapes_update_for_any_finite_input(
        p: AdaptationParams, probes: list[tuple[float, float, float, list[float]]]) -> None:
    a = Adapter(p, 2)
    with np.errstate(over="raise", invalid="raise", divide="raise"):  # no silent inf/NaN
        for dt, measured, model, terms in probes:
            a.advance(dt)
            before = a.correction_um(terms) if all(abs(t) <= MAX_INPUT_UM for t in terms) \
                else None
            out = a.update(measured, model, terms)
            assert out.accepted == (out.reason is None)
            assert math.isfinite(out.bias_um) and math.isfinite(out.bias_sigma_um)
            assert abs(a.bias_um) <= p.max_total_um * (1 + 1e-12)
            assert all(abs(g) <= p.max_gain * (1 + 1e-12) for g in a.gain_corrections)
            if before is not None:
                change = a.correction_um(terms) - before
                assert abs(change) <= p.max_step_um * (1 + 1e-9) + 1e-9
            a.refuse("fault", measured, model, terms)
            _finite_state(a)
        back = Adapter.from_state(p, 2, json.loads(json.dumps(a.export_state())))
    assert back.export_state() == a.export_state()


def test_a_probe_beyond_a_metre_is_refused_not_weighed() -> None:
    a = Adapter(AdaptationParams(gains=True, gate_sigma=1e6, max_total_um=1e6,
                                 max_step_um=1e6), 1)
    for measured, model, term in ((1e300, 0.0, 1.0), (0.0, -1e300, 1.0), (1.0, 0.0, 1e300)):
        with np.errstate(over="raise", invalid="raise", divide="raise"):
            out = a.update(measured, model, [term])
        assert not out.accepted and out.reason == "fault"
    assert a.bias_um == 0.0 and a.accepted == 0


@settings(max_examples=300, deadline=None)
@given(st.fixed_dictionaries({
    "x": st.lists(any_finite, min_size=1, max_size=1),
    "applied": st.lists(any_finite, min_size=1, max_size=1),
    "P": st.lists(st.lists(any_finite, min_size=1, max_size=1), min_size=1, max_size=1),
    "pending_s": any_finite,
}), st.lists(probe, max_size=3))
def test_a_restore_from_any_finite_state_is_an_estimator_or_a_named_refusal(
        fields: dict[str, Any], probes: list[tuple[float, float, float, list[float]]]) -> None:
    p = AdaptationParams()
    state = {"version": 2, "n_terms": 1, "gains": False, "accepted": 0, "refused": 0,
             "applied_moves": 0, **fields}
    with np.errstate(over="raise", invalid="raise", divide="raise"):
        try:
            a = Adapter.from_state(p, 1, state)
        except ValueError as exc:
            assert str(exc).startswith("adaptation state:")
            return
        for dt, measured, model, terms in probes:
            a.advance(dt)
            a.update(measured, model, terms[:1])
    _finite_state(a)


@pytest.mark.parametrize(("name", "value"), [
    ("max_total_um", 1e308), ("probe_noise_um", 1e160), ("bias_rw_um_per_sqrt_h", 1e160),
    ("max_gain", 1e200), ("gain_rw_per_sqrt_h", 1e160), ("gate_sigma", 1e300),
    ("max_step_um", 1e300), ("initial_bias_sigma_um", 1e200), ("probe_noise_um", 1e-300),
])
def test_a_setting_beyond_the_domain_is_refused_by_name(name: str, value: float) -> None:
    """Refused by name where the estimator would raise OverflowError (at its start,
    or at the first probe)."""
    settings: dict[str, Any] = {name: value, "gains": True}
    with pytest.raises(ValueError, match=f"^{name}: must be"):
        AdaptationParams(**settings)


@settings(max_examples=200, deadline=None)
@given(st.sampled_from(sorted(DOMAIN)), any_finite)
def test_any_finite_setting_is_either_an_estimator_or_a_value_error(name: str,
                                                                    value: float) -> None:
    settings: dict[str, Any] = {name: value, "gains": True}
    try:
        p = AdaptationParams(**settings)
    except ValueError as exc:
        assert str(exc).startswith(f"{name}: ") or "max_gain" in str(exc)
        return
    with np.errstate(over="raise", invalid="raise", divide="raise"):
        a = Adapter(p, 1)
        a.advance(1e9)
        a.update(1.0, 0.0, [1.0])
    _finite_state(a)
