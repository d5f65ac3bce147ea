"""The machine as a shop runs it, in the pure cycle: the reference state, the
warm start, the re-zero, and the controller's permission to change the offset.

SP2 (bearing and ambient terms): 1 K on the bearing is 16.0 µm on the first
sample and (16.0005 - 15.9975)/(1 - 0.99983) ≈ 17.6 µm at steady state."""

from __future__ import annotations

from itertools import pairwise

import pytest

from compd.core.cycle import Cycle
from compd.core.events import EventName
from compd.core.health import Cause
from compd.core.modelstep import MAX_ADVANCE_STEPS
from compd.core.output import Status
from compd.testing import FakeClock
from tests.compd.core.cycle_helpers import SLEW_UM_S, params, samples, sp2
from tests.shipped import EXAMPLES

REF = {"bearing": 20.0, "ambient": 20.0}


def _model(reference: dict[str, float] | None = None):  # type: ignore[no-untyped-def]
    m = sp2()
    if reference is not None:
        m.calibration_reference = dict(reference)
    return m


def _names(events: tuple) -> list[str]:  # type: ignore[type-arg]
    return [str(e.name) for e in events]


def _all(rows: list) -> list[str]:  # type: ignore[type-arg]
    return [n for r in rows for n in _names(r.events)]


def _run(cycle: Cycle, clock: FakeClock, n: int, bearing: float, **kw: object) -> list:  # type: ignore[type-arg]
    rows = []
    for _ in range(n):
        t = clock.tick()
        cycle.plan(t, samples(t, bearing), **kw)  # type: ignore[arg-type]
        rows.append(cycle.commit())
    return rows


# -- reference and warm start ---------------------------------------------------------


def test_a_warm_first_start_with_a_calibration_reference_predicts_the_heat_it_holds() -> None:
    warm = _run(Cycle(params(), _model(REF)), FakeClock(), 1, bearing=20.5)[0]
    init = next(e for e in warm.events if e.name is EventName.MODEL_INITIALISED)
    assert init.fields["mode"] == "steady_state" and init.fields["reference"] == "calibration"
    steady = 0.5 * (16.0005 - 15.9975) / (1 - 0.99983)  # DC gain · 0.5 K
    assert init.fields["steady_um"] == pytest.approx(steady, rel=1e-3)
    assert warm.model_um == pytest.approx(steady, rel=1e-3)

    cold = _run(Cycle(params(), _model()), FakeClock(), 1, bearing=20.5)[0]
    init = next(e for e in cold.events if e.name is EventName.MODEL_INITIALISED)
    assert init.fields["mode"] == "first_start" and init.fields["reference"] == "first_sample"
    assert cold.model_um == pytest.approx(0.0, abs=1e-9)  # the old behaviour, now said


def test_a_too_old_checkpoint_is_advanced_over_the_gap_with_the_inputs_held() -> None:
    clock = FakeClock()
    first = Cycle(params(), _model(REF))
    _run(first, clock, 200, bearing=20.0)
    _run(first, clock, 300, bearing=20.4)  # heating: far from its steady state
    state = first.export_state()
    gap_s = 600.0
    # what stepping on for the gap at today's inputs gives, then one more step
    reference = _model(REF)
    reference.import_state(state["model"])
    for _ in range(round(gap_s) + 1):
        expected = reference.step({"bearing": 20.4, "ambient": 20.0})
    again = Cycle.from_state(params(), _model(REF), None, state, fresh=False, age_s=gap_s)
    row = _run(again, clock, 1, bearing=20.4)[0]
    init = next(e for e in row.events if e.name is EventName.MODEL_INITIALISED)
    assert init.fields["mode"] == "advanced" and init.fields["steps"] == round(gap_s)
    assert row.model_um == pytest.approx(expected, abs=1e-9)
    assert row.snapshot.model_start == "advanced"

    far = Cycle.from_state(params(), _model(REF), None, state, fresh=False,
                           age_s=(MAX_ADVANCE_STEPS + 1) * 1.0)
    row = _run(far, clock, 1, bearing=20.4)[0]
    init = next(e for e in row.events if e.name is EventName.MODEL_INITIALISED)
    assert init.fields["mode"] == "steady_state"
    assert init.fields["not_advanced"]["reason"] == "gap beyond the advance horizon"


# -- re-zero --------------------------------------------------------------------------


def test_rezero_takes_the_prediction_as_zero_and_ramps_with_no_step() -> None:
    clock = FakeClock()
    cycle = Cycle(params(), _model(REF))
    rows = _run(cycle, clock, 60, bearing=22.0)  # warm from the start: ≈ 35 µm
    before = rows[-1]
    assert before.stage_um > 30.0
    event = cycle.rezero("test", wall_s=1.0)
    assert event.name is EventName.REZERO and event.fields["zero_um"] == pytest.approx(
        cycle.models.last_raw_um)
    rows = _run(cycle, clock, 60, bearing=22.0)
    offsets = [before.stage_um] + [r.stage_um for r in rows]
    steps = [abs(b - a) for a, b in pairwise(offsets)]
    assert max(steps) <= SLEW_UM_S * 1.0 + 1e-12  # never more than the slew limit
    assert abs(rows[-1].model_um or 0.0) < 1.0 and abs(rows[-1].stage_um) < 1.0
    # the re-zero survives a restart, fresh or not, and goes with another model
    state = cycle.export_state()
    assert state["zero"]["by"] == "test"
    for fresh in (True, False):
        again = Cycle.from_state(params(), _model(REF), None, state, fresh=fresh, age_s=5.0)
        assert again.models.zero_um == pytest.approx(cycle.models.zero_um)
        row = _run(again, clock, 1, bearing=22.0)[0]  # restarted: still the growth since
        assert abs(row.model_um or 0.0) < 1.0
    other = Cycle.from_state(params(), _model(REF), None, state, fresh=False,
                             same_model=False)
    assert other.models.zero_um == 0.0
    assert _names(_run(other, clock, 1, bearing=22.0)[0].events).count("rezero_dropped") == 1


def test_rezero_before_any_prediction_is_refused() -> None:
    event = Cycle(params(), _model(REF)).rezero("early")
    assert event.name is EventName.REZERO_REFUSED


def test_rezero_input_acts_on_its_rising_edge_only() -> None:
    clock = FakeClock()
    cycle = Cycle(params(), _model(REF))
    # high from the start (a bit left set): no edge, no re-zero
    rows = _run(cycle, clock, 5, bearing=20.3, rezero_bit=True)
    assert "rezero" not in _all(rows)
    rows = _run(cycle, clock, 2, bearing=20.3, rezero_bit=None)  # unreadable: no edge
    rows += _run(cycle, clock, 1, bearing=20.3, rezero_bit=True)
    assert "rezero" not in _all(rows)
    rows = _run(cycle, clock, 1, bearing=20.3, rezero_bit=False)
    rows += _run(cycle, clock, 3, bearing=20.3, rezero_bit=True)  # one pulse, held high
    assert _all(rows).count("rezero") == 1
    assert cycle.models.zero_by == "controller input [output] rezero"


# -- the controller's permission ------------------------------------------------------


def test_no_permission_holds_the_offset_while_the_model_steps_then_ramps() -> None:
    clock = FakeClock()
    cycle = Cycle(params(), _model(REF))
    _run(cycle, clock, 5, bearing=20.0)
    held = _run(cycle, clock, 60, bearing=20.3, permitted=False)
    assert "permission_waiting" in _names(held[0].events)
    assert all(r.stage_um == held[0].stage_um for r in held)
    last = held[-1]
    assert last.cause is Cause.WAITING_FOR_PERMISSION and last.cause.healthy
    assert last.status & Status.HOLDING and not last.status & (Status.OK | Status.ALARM)
    assert last.model_um is not None and last.model_um > 4.0  # the model kept stepping
    assert last.snapshot.pending_um == pytest.approx(last.model_um - last.stage_um)
    assert last.in_force  # what is wanted is held on purpose: complete, like an operator hold
    go = _run(cycle, clock, 10, bearing=20.3, permitted=True)
    assert "permission_granted" in _names(go[0].events)
    offsets = [last.stage_um] + [r.stage_um for r in go]
    assert max(abs(b - a) for a, b in pairwise(offsets)) \
        <= SLEW_UM_S + 1e-12
    assert go[-1].stage_um == pytest.approx(go[-1].model_um, abs=0.5)
    assert go[-1].snapshot.pending_um is None


def test_an_unreadable_permit_is_not_permitted_and_unhealthy() -> None:
    clock = FakeClock()
    cycle = Cycle(params(), _model(REF))
    _run(cycle, clock, 5, bearing=20.0)
    rows = _run(cycle, clock, 10, bearing=20.3, permitted=None)
    assert "permit_unreadable" in _names(rows[0].events)
    assert all(r.stage_um == rows[0].stage_um for r in rows)
    assert rows[-1].cause is Cause.PERMIT_UNREADABLE and not rows[-1].cause.healthy
    assert not rows[-1].in_force


def test_a_fault_ramps_to_zero_whatever_the_permit() -> None:
    clock = FakeClock()
    cycle = Cycle(params(hold_s=5.0), _model(REF))
    rows = _run(cycle, clock, 40, bearing=20.3)
    start = rows[-1].stage_um
    for _ in range(20):  # the bearing opens: hold 5 s, then ramp to zero
        t = clock.tick()
        cycle.plan(t, samples(t, 900.0), permitted=False)
        row = cycle.commit()
    assert str(row.state) == "ramp" and row.stage_um < start


# -- the config -----------------------------------------------------------------------

_EXAMPLES = EXAMPLES


def _example(tmp_path, name: str, after: str, extra: str):  # type: ignore[no-untyped-def]
    from compd.config.loader import load_config

    text = (_EXAMPLES / name).read_text()
    assert after in text
    path = tmp_path / name
    path.write_text(text.replace(after, after + "\n" + extra, 1))
    return load_config(path)


def test_linuxcnc_update_permitted_is_a_hal_pin_read_with_the_state(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from drivers.addresses import LinuxCncPin

    cfg = _example(tmp_path, "linuxcnc.toml", "[output]",
                   'update_permitted = { pin = "update-permitted", net = "compd-permit", '
                   'type = "bit" }\nrezero = { pin = "rezero", net = "compd-rezero", '
                   'type = "bit" }')
    permit = cfg.states["update_permitted"]
    assert isinstance(permit, LinuxCncPin) and permit.pin == "update-permitted"
    assert isinstance(cfg.states["rezero"], LinuxCncPin)


def test_a_config_reference_is_the_models_and_checked(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from compd.errors import ConfigError

    cfg = _example(tmp_path, "modbus.toml", "[model]",
                   "reference = { bearing = 20.0, motor = 20.0, column = 20.0, ambient = 20.0 }")
    assert cfg.model.calibration_reference == {"ambient": 20.0, "bearing": 20.0,
                                               "column": 20.0, "motor": 20.0}
    plain = _example(tmp_path, "modbus.toml", "[model]", "")
    assert plain.model_sha256 != cfg.model_sha256  # another reference is another model
    with pytest.raises(ConfigError, match=r"model\.reference.*no reference temperature"):
        _example(tmp_path, "modbus.toml", "[model]", "reference = { bearing = 20.0 }")
    with pytest.raises(ConfigError, match=r"model\.reference.*no channel 'spindle'"):
        _example(tmp_path, "modbus.toml", "[model]", "reference = { spindle = 20.0 }")
