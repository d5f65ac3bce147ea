"""Refusals that agree in direction re-acquire (models.adaptation)."""

from __future__ import annotations

import itertools
import json

import pytest

from models.adaptation import AdaptationParams, Adapter

HOUR = 3600.0


def _settled(**kw: float) -> Adapter:
    """An estimator that has seen the model right for a day of probes (σ small)."""
    a = Adapter(AdaptationParams(score_window=0, **kw), 1)  # type: ignore[arg-type]
    for _ in range(24):
        a.advance(HOUR)
        assert a.update(0.0, 0.0, []).accepted
    return a


def test_a_real_step_is_refused_then_reacquired_and_followed_within_the_step_bound() -> None:
    a = _settled()
    outs = []
    for _ in range(8):  # the machine really moved by 15 µm
        a.advance(HOUR)
        outs.append(a.update(15.0, 0.0, []))
    assert [o.accepted for o in outs[:3]] == [False, False, True]
    assert [o.reason for o in outs[:2]] == ["gate", "gate"]
    assert outs[2].reacquired and a.reacquisitions == 1
    assert outs[2].estimated_bias_um == pytest.approx(15.0, abs=1.0)  # re-baselined
    # the applied correction follows by at most max_step_um per probe
    applied = [0.0] + [o.bias_um for o in outs]
    assert max(abs(b - c) for b, c in itertools.pairwise(applied)) \
        <= a.params.max_step_um + 1e-9
    assert all(o.accepted for o in outs[3:])  # after it, the probes are accepted again
    assert a.correction_um([]) == pytest.approx(15.0, abs=2.0)  # within the apply band


def test_refusals_that_do_not_agree_in_direction_never_reacquire() -> None:
    a = _settled()
    for z in (15.0, -15.0, 15.0, -15.0, 15.0, -15.0):  # chips, both ways
        a.advance(HOUR)
        assert not a.update(z, 0.0, []).accepted
    assert a.reacquisitions == 0 and a.correction_um([]) == 0.0


def test_a_change_beyond_what_the_correction_may_hold_is_never_reacquired() -> None:
    a = _settled()
    for _ in range(10):  # 500 µm: no thermal drift, a broken probe or set-up
        a.advance(HOUR)
        assert a.update(500.0, 0.0, []).reason == "gate"
    assert a.reacquisitions == 0 and a.correction_um([]) == 0.0


def test_reacquire_after_0_refuses_forever_and_the_streak_survives_a_checkpoint() -> None:
    a = _settled(reacquire_after=0)
    for _ in range(6):
        a.advance(HOUR)
        assert not a.update(15.0, 0.0, []).accepted
    b = _settled()
    for _ in range(2):
        b.advance(HOUR)
        b.update(15.0, 0.0, [])
    c = Adapter.from_state(b.params, 1, json.loads(json.dumps(b.export_state())))
    c.advance(HOUR)
    assert c.update(15.0, 0.0, []).reacquired  # the third in a row, across the restart
