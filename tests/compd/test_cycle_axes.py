"""The per-axis lines in the pure cycle (`compd.core.axes`): each axis a separate
output of the one cycle, its value and slope each through its own stage, its own
fault policy, read-back and write health; the offset's behaviour unchanged."""

from __future__ import annotations

import itertools
import math
from pathlib import Path
from typing import Any

import pytest

from compd.core.axes import AxisParams
from compd.core.cycle import Cycle, Outcome
from compd.core.events import Event, EventName
from compd.core.faults import FaultState
from compd.core.health import Cause
from compd.core.validation import ChannelLimits
from compd.testing import FakeClock
from drivers.base import Sample
from models.compensation import CompensationModel
from models.modelfile import parse_model
from tests.compd.cycle_helpers import params, samples, sp2


def static(name: str, gains: dict[str, float]) -> CompensationModel:
    """y = Σ gain·(T - 20 °C): a static line of the temperatures (µm or µm/m)."""
    return parse_model({"model": {"name": name, "period_s": 1.0},
                        "terms": [{"name": name, "inputs": gains, "a": ["1"], "b": ["1"]}],
                        "reference": dict.fromkeys(gains, 20.0)})


def x_axis(**over: Any) -> AxisParams:
    base: dict[str, Any] = dict(
        axis="x", value_model=static("value", {"nut": 2.0}),
        slope_model=static("slope", {"nut": 3.0}), reference_mm=25.0,
        value_limit_um=50.0, slope_limit_um_m=12.0, value_slew_um_s=1.0,
        slope_slew_um_m_s=0.5)
    base.update(over)
    return AxisParams(**base)


def axis_params(readback: bool = False, **over: Any) -> Any:
    chans = dict(params().channels)
    chans["nut"] = ChannelLimits(-20.0, 150.0, max_rate_per_s=0.5, stale_after_s=30.0)
    return params(channels=chans, axes=(x_axis(**over),), readback=readback)


def inputs(t: float, nut: float = 25.0, bearing: float = 25.0) -> dict[str, Sample]:
    return {**samples(t, bearing), "nut": Sample(nut, t)}


def test_value_and_slope_each_through_their_own_stage() -> None:
    cycle = Cycle(axis_params(), sp2())
    clock = FakeClock(period_s=1.0)
    sent = []
    for _ in range(40):
        t = clock.tick()
        plan = cycle.plan(t, inputs(t))
        row = cycle.commit()
        sent.append((plan.writes["x_comp_value"], plan.writes["x_comp_slope"]))
        # one write: the offset, heartbeat and status beside the axis's three parameters
        assert {"offset", "heartbeat", "status", "x_comp_reference"} <= set(plan.writes)
        assert plan.writes["x_comp_reference"] == 25.0
    # value: 2·5 = 10 µm at 1 µm/s; slope: 3·5 = 15 µm/m clamped to 12, at 0.5 µm/m/s
    assert sent[0] == (1.0, 0.5)
    assert sent[9] == (10.0, 5.0)
    assert sent[-1] == (10.0, 12.0)
    steps = [abs(b[1] - a[1]) for a, b in itertools.pairwise(sent)]
    assert max(steps) <= 0.5 + 1e-12
    x = row.axes["x"]
    assert x.state == FaultState.OK and x.cause == Cause.AT_LIMIT
    assert x.value.model == pytest.approx(10.0) and x.slope.model == pytest.approx(15.0)
    assert x.slope.confirmed == 12.0 and not x.in_force  # clamped: not what the model asks
    assert row.cause.healthy  # the offset's own health is its own


def test_an_invalid_axis_input_holds_that_axis_while_z_goes_on() -> None:
    cycle = Cycle(axis_params(), sp2())
    clock = FakeClock(period_s=1.0)
    for _ in range(20):
        t = clock.tick()
        cycle.plan(t, inputs(t))
        row = cycle.commit()
    held = row.axes["x"].value.stage, row.axes["x"].slope.stage
    z_before = row.stage_um
    events: list[Event] = []
    for _ in range(30):
        t = clock.tick()
        plan = cycle.plan(t, inputs(t, nut=math.nan, bearing=25.5))
        row = cycle.commit()
        events.extend(plan.events)
        assert (plan.writes["x_comp_value"], plan.writes["x_comp_slope"]) == held
    x = row.axes["x"]
    assert x.state == FaultState.HOLD and x.cause == Cause.INPUTS_INVALID
    assert x.status & 2  # HOLDING in the axis's own status word
    assert row.state == FaultState.OK and row.stage_um != z_before  # Z tracks on
    hold = [e for e in events if e.name is EventName.FAULT_HOLD]
    assert len(hold) == 1 and hold[0].fields["axis"] == "x"
    # past hold_s the axis ramps its value and slope to 0 at their own rates, alarmed
    for _ in range(40):
        t = clock.tick()
        plan = cycle.plan(t, inputs(t, nut=math.nan, bearing=25.5))
        row = cycle.commit()
    x = row.axes["x"]
    assert x.state == FaultState.RAMP and x.status & 8
    assert x.value.stage == pytest.approx(held[0] - 10.0) or x.value.stage == 0.0
    assert row.state == FaultState.OK


def _warm(cycle: Cycle, clock: FakeClock, n: int, rb: dict[str, float | None] | None = None
          ) -> Any:
    row = None
    for _ in range(n):
        t = clock.tick()
        back = rb if rb is not None else {
            "x_comp_value": cycle.axes.axes[0].value.stage.confirmed_um,
            "x_comp_slope": cycle.axes.axes[0].slope.stage.confirmed_um,
            "x_comp_reference": 25.0}
        cycle.plan(t, inputs(t), 0.0 if cycle.output.confirmed_um is None
                   else cycle.output.confirmed_um, axes_readback=back)
        row = cycle.commit()
    return row


def test_another_writer_of_an_axis_parameter_is_detected_and_ramped_from() -> None:
    cycle = Cycle(axis_params(readback=True), sp2())
    clock = FakeClock(period_s=1.0)
    _warm(cycle, clock, 1, {"x_comp_value": 0.0, "x_comp_slope": 0.0,
                            "x_comp_reference": 0.0})
    row = _warm(cycle, clock, 20)
    assert row.axes["x"].value.confirmed == 10.0
    # a second client wrote 30 µm to the value
    t = clock.tick()
    plan = cycle.plan(t, inputs(t), cycle.output.confirmed_um, axes_readback={
        "x_comp_value": 30.0, "x_comp_slope": row.axes["x"].slope.confirmed,
        "x_comp_reference": 25.0})
    row = cycle.commit()
    found = [e for e in plan.events if e.name is EventName.READBACK_MISMATCH]
    assert found and found[0].fields["output"] == "x_comp_value"
    assert found[0].fields["axis"] == "x"
    assert row.axes["x"].cause == Cause.FOREIGN_OFFSET and row.axes["x"].status & 8
    assert plan.writes["x_comp_value"] == 29.0  # ramped from it, never a step
    assert row.cause.healthy  # Z's health is its own


def test_a_controller_restart_resumes_without_a_jump() -> None:
    cycle = Cycle(axis_params(readback=True), sp2())
    clock = FakeClock(period_s=1.0)
    _warm(cycle, clock, 1, {"x_comp_value": 0.0, "x_comp_slope": 0.0,
                            "x_comp_reference": 0.0})
    row = _warm(cycle, clock, 30)
    assert row.axes["x"].value.confirmed == 10.0 and row.axes["x"].slope.confirmed == 12.0
    # the controller restarted: every parameter back at 0
    t = clock.tick()
    plan = cycle.plan(t, inputs(t), cycle.output.confirmed_um, axes_readback={
        "x_comp_value": 0.0, "x_comp_slope": 0.0, "x_comp_reference": 0.0})
    cycle.commit()
    assert plan.writes["x_comp_value"] == 1.0 and plan.writes["x_comp_slope"] == 0.5
    assert plan.writes["x_comp_reference"] == 25.0


def test_a_daemon_restart_resumes_each_axis_from_the_checkpoint() -> None:
    p = axis_params(readback=True)
    cycle = Cycle(p, sp2())
    clock = FakeClock(period_s=1.0)
    _warm(cycle, clock, 1, {"x_comp_value": 0.0, "x_comp_slope": 0.0,
                            "x_comp_reference": 0.0})
    _warm(cycle, clock, 12)
    state = cycle.export_state()
    assert state["axes"]["x"]["value"] == 10.0 and state["axes"]["x"]["slope"] == 6.5
    again = Cycle.from_state(p, sp2(), None, state, fresh=True)
    first = again.axes.axes[0]
    assert first.value.stage.current_um == 10.0 and first.value.stage.confirmed_um == 10.0
    assert first.value.models is not None and first.value.models.init_mode == "restored"
    t = clock.tick()
    plan = again.plan(t, inputs(t), again.output.confirmed_um, axes_readback={
        "x_comp_value": 10.0, "x_comp_slope": 6.5, "x_comp_reference": 25.0})
    row = again.commit()
    assert not [e for e in plan.events if e.name is EventName.READBACK_MISMATCH]
    assert (plan.writes["x_comp_value"], plan.writes["x_comp_slope"]) == (10.0, 7.0)
    assert row.axes["x"].cause == Cause.AT_LIMIT or row.axes["x"].value.model == 10.0
    # too old: the filters start at the steady state of today's inputs, the stage from
    # what the controller confirmed
    stale = Cycle.from_state(p, sp2(), None, state, fresh=False)
    assert stale.axes.axes[0].value.stage.current_um == 10.0


def test_a_refused_axis_write_counts_against_that_axis() -> None:
    cycle = Cycle(axis_params(), sp2())
    clock = FakeClock(period_s=1.0)
    for _ in range(5):
        t = clock.tick()
        cycle.plan(t, inputs(t))
        cycle.commit()
    t = clock.tick()
    cycle.plan(t, inputs(t))
    row = cycle.commit(Outcome.failed("x_comp_slope", permanent=True, reason="refused"))
    assert row.axes["x"].cause == Cause.WRITE_STOPPED
    assert any(e.name is EventName.OFFSET_WRITE_STOPPED and e.fields["axis"] == "x"
               for e in row.write_events)
    t = clock.tick()
    plan = cycle.plan(t, inputs(t))
    row = cycle.commit()
    assert "x_comp_value" not in plan.writes and "offset" in plan.writes
    assert row.axes["x"].state == FaultState.STOPPED and row.state == FaultState.OK


def test_no_axes_no_axis_report() -> None:
    cycle = Cycle(params(), sp2())
    t = 1.0
    plan = cycle.plan(t, samples(t, 25.0))
    row = cycle.commit()
    assert dict(row.axes) == {} and not any("comp" in n for n in plan.writes)
    assert "axes" not in cycle.export_state()


def test_the_status_document_says_which_axes_are_in_force(tmp_path: Path) -> None:
    from compd.config.loader import load_config
    from compd.core.params import params_from_config
    from compd.faces.status import StatusBoard
    from tests.compd.axes_helpers import write_axes_config

    cfg = load_config(write_axes_config(tmp_path, period_s=1.0, time_scale=1.0,
                                        timeout_s=0.2))
    cycle, board = Cycle(params_from_config(cfg), cfg.model), StatusBoard()
    clock = FakeClock(period_s=1.0)
    temps = {"nut": 20.0, "screw_bearing": 20.0, "column": 20.0, "ambient": 20.0}
    for nut in (20.0, math.nan):
        t = clock.tick()
        back = {n: 0.0 for n in cycle.axes.names}
        cycle.plan(t, {k: Sample(v, t) for k, v in {**temps, "nut": nut}.items()}, 0.0,
                   axes_readback=back)
        board.publish(cycle.commit(), cfg)
        x = board.snapshot["axes"]["x"]
        if nut == 20.0:
            assert x["in_force"] and x["cause"] == "in_force"
            assert "axes in force: x" in board.snapshot["why"]
        else:
            assert not x["in_force"] and x["state"] == "hold"
            assert x["cause"] == "inputs_invalid" and x["status_word"] & 2
            assert "axes in force: none" in board.snapshot["why"]
