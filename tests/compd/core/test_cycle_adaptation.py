"""Probe-assisted adaptation in the pure cycle (`compd.core.adaptation`), on a fake clock."""

from __future__ import annotations

import itertools
import math
from typing import Any

import pytest

from compd.core.adaptation import AdaptationSettings, ProbeReading
from compd.core.cycle import Cycle
from compd.core.plan import Row
from compd.testing import FakeClock
from models.adaptation import AdaptationParams
from tests.compd.core.cycle_helpers import PERIOD_S, SLEW_UM_S, params, samples, sp2

#: a probe every 5 machine minutes in these tests (the filter does not care how often)
EVERY = 300


def _settings(mode: str = "apply", measures: str = "residual",
              **est: float) -> AdaptationSettings:
    return AdaptationSettings(mode=mode, measures=measures,  # type: ignore[arg-type]
                              params=AdaptationParams(**est))  # type: ignore[arg-type]


class Machine:
    """The cycle against a machine whose real growth is the model's plus `bias_um`;
    a measuring cycle every EVERY s leaves growth - offset held + `spoil` in the
    controller and advances the counter."""

    def __init__(self, cycle: Cycle, bias_um: float) -> None:
        self.cycle, self.bias_um = cycle, bias_um
        self.clock = FakeClock()
        self.counter = 7.0  # whatever the controller shows at start
        self.value = 0.0
        self.held = 0.0  # what the controller holds (confirmed writes)
        self.results: list[Row] = []

    def run(self, n: int, *, bearing: float = 25.0, spoil: float = 0.0,
            invalid_at: int | None = None) -> list[Row]:
        out = []
        for _ in range(n):
            t = self.clock.tick()
            k = len(self.results)
            if k and k % EVERY == 0:
                model = self.results[-1].model_um or 0.0
                self.value = model + self.bias_um - self.held + spoil
                self.counter += 1
            s = samples(t, math.nan if k == invalid_at else bearing)
            self.cycle.plan(t, s, probe=ProbeReading(self.value, self.counter))
            r = self.cycle.commit()
            self.held = r.stage_um
            self.results.append(r)
            out.append(r)
        return out


def _probes(results: list[Row]) -> list[dict[str, Any]]:  # as RecordRow.probe
    return [dict(r.probe) for r in results if r.probe is not None]


def test_a_constant_bias_is_learnt_and_reaches_the_tool_within_the_slew_limit() -> None:
    m = Machine(Cycle(params(adaptation=_settings()), sp2()), bias_um=6.0)
    results = m.run(EVERY * 8)
    probes = _probes(results)
    assert len(probes) == 7 and all(p["accepted"] for p in probes)
    # the correction went to the tool: the offset follows model + correction (the
    # estimator applies what departs from zero by more than its band: most of the 6 µm)
    last = results[-1]
    correction = last.contributions["adaptation"]
    assert 4.0 < correction <= 6.5
    assert last.model_um is not None
    assert last.stage_um == pytest.approx(last.model_um + correction, abs=0.05)
    steps = [abs(b.stage_um - a.stage_um) for a, b in itertools.pairwise(results)]
    assert max(steps) <= SLEW_UM_S * PERIOD_S + 1e-9  # never a jump at the tool


def test_shadow_mode_estimates_and_records_but_never_applies() -> None:
    m = Machine(Cycle(params(adaptation=_settings("shadow")), sp2()), bias_um=6.0)
    results = m.run(EVERY * 8)
    assert all(p["accepted"] and p["mode"] == "shadow" for p in _probes(results))
    cycle = m.cycle
    assert cycle.probes is not None and cycle.probes.adapter.estimated_bias_um > 4.0
    # the recorded proposal is there, the tool never saw it
    assert results[-1].contributions["adaptation"] > 4.0
    for r in results:
        assert r.model_um is not None and r.stage_um == pytest.approx(r.model_um, abs=1.0)


def test_the_same_counter_twice_is_one_probe_and_the_first_one_seen_is_a_baseline() -> None:
    m = Machine(Cycle(params(adaptation=_settings()), sp2()), bias_um=3.0)
    results = m.run(EVERY * 3)  # counter 7 at start (a baseline), then 8, 9
    assert [p["counter"] for p in _probes(results)] == [8.0, 9.0]


def test_a_bad_probe_is_refused_and_never_learnt() -> None:
    m = Machine(Cycle(params(adaptation=_settings()), sp2()), bias_um=0.0)
    m.run(EVERY * 4)
    before = m.cycle.probes.adapter.estimated_bias_um if m.cycle.probes else math.nan
    bad = m.run(EVERY, spoil=50.0)  # a chip under the probe
    probe = _probes(bad)[0]
    assert probe["accepted"] is False and probe["reason"] == "gate"
    assert probe["innovation_um"] is not None and float(probe["innovation_um"]) > 40.0
    assert m.cycle.probes is not None
    assert m.cycle.probes.adapter.estimated_bias_um == before
    assert any(e.name == "probe_refused" for r in bad for e in r.events)


def test_a_probe_while_the_inputs_are_invalid_is_refused() -> None:
    m = Machine(Cycle(params(adaptation=_settings()), sp2()), bias_um=4.0)
    results = m.run(EVERY * 2 + 1, invalid_at=EVERY * 2)  # the probe lands on a bad sample
    probes = _probes(results)
    assert probes[-1]["accepted"] is False and probes[-1]["reason"] == "fault"


def test_the_estimator_survives_a_checkpoint_and_another_model_clears_it() -> None:
    m = Machine(Cycle(params(adaptation=_settings()), sp2()), bias_um=5.0)
    m.run(EVERY * 6)
    state = m.cycle.export_state()
    assert state["adaptation"]["counter"] == m.counter
    same = Cycle.from_state(params(adaptation=_settings()), sp2(), None, state, fresh=True)
    other = Cycle.from_state(params(adaptation=_settings()), sp2(), None, state, fresh=True,
                             same_model=False)
    assert same.probes is not None and other.probes is not None and m.cycle.probes is not None
    assert same.probes.adapter.estimated_bias_um == m.cycle.probes.adapter.estimated_bias_um
    assert same.probes.counter == m.counter  # the next probe is new, this one is not
    assert other.probes.adapter.estimated_bias_um == 0.0 and other.probes.counter is None


def test_a_garbled_estimator_state_starts_afresh_with_an_event() -> None:
    state = {"model": None, "offset_um": 0.0, "adaptation": {"estimator": {"x": "junk"}}}
    cycle = Cycle.from_state(params(adaptation=_settings()), sp2(), None, state, fresh=True)
    t = 1.0
    r = cycle.plan(t, samples(t, 25.0))
    assert "adaptation_state_refused" in [e.name for e in r.events]
    assert cycle.probes is not None and cycle.probes.adapter.estimated_bias_um == 0.0


def test_the_displacement_convention_takes_the_value_as_measured() -> None:
    cfg = params(adaptation=_settings(measures="displacement"))
    cycle, clock = Cycle(cfg, sp2()), FakeClock()
    t = clock.tick()
    cycle.plan(t, samples(t, 25.0), probe=ProbeReading(0.0, 1.0))  # baseline
    cycle.commit()
    t = clock.tick()
    r = cycle.plan(t, samples(t, 25.0), probe=ProbeReading(3.0, 2.0))
    assert r.probe is not None and r.probe["measured_um"] == 3.0
