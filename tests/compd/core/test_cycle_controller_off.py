"""The controller takes no offset (machine off, E-stop: `[output] machine_on`,
`estop`): the cycle holds, writes no offset, keeps stepping the model, and
when the machine is on again ramps from what the controller then holds
(LinuxCNC zeroes its external offset at machine on), with no alarm."""

from __future__ import annotations

from pathlib import Path

from compd.core.cycle import Cycle
from compd.core.faults import FaultState
from compd.core.health_view import HealthView, recorded_state, status_word
from compd.core.output import Status
from compd.testing import FakeClock
from tests.compd.core.cycle_helpers import PERIOD_S, SLEW_UM_S, params, samples, sp2


def _heated() -> tuple[Cycle, FakeClock, float]:
    cycle, clock = Cycle(params(readback=True), sp2()), FakeClock()
    held = 0.0
    for bearing in [20.0] + [22.0] * 60:
        t = clock.tick()
        cycle.plan(t, samples(t, bearing), held)
        r = cycle.commit()
        held = r.writes.get("offset", held)
    assert held > 30.0
    return cycle, clock, held


def test_machine_off_holds_without_writing_and_keeps_the_model_going() -> None:
    cycle, clock, held = _heated()
    heartbeat = cycle.heartbeat
    t = clock.tick()
    cycle.plan(t, samples(t, 22.0), held, controller_off="machine_off")
    r = cycle.commit()
    assert [e.name for e in r.events] == ["controller_off"]
    assert r.events[0].fields == {"reason": "machine_off", "offset_um": held}
    for _ in range(20):
        t = clock.tick()
        cycle.plan(t, samples(t, 22.0), held, controller_off="machine_off")
        r = cycle.commit()
        assert "offset" not in r.writes  # no write fight with a machine that is off
        assert r.stage_um == held
        assert r.status & Status.CONTROLLER_OFF and r.status & Status.HOLDING
        assert not r.status & (Status.OK | Status.ALARM | Status.READBACK_MISMATCH)
        assert r.state == FaultState.HOLD and r.inputs_valid and not r.in_force
        assert "heartbeat" in r.writes and "status" in r.writes
        assert r.events == ()
    assert cycle.heartbeat == (heartbeat + 21) % 32768  # the model stepped every cycle


def test_machine_on_again_ramps_from_zero_without_alarm() -> None:
    cycle, clock, held = _heated()
    for _ in range(5):
        t = clock.tick()
        cycle.plan(t, samples(t, 22.0), held, controller_off="estop")
        cycle.commit()
    t = clock.tick()
    cycle.plan(t, samples(t, 22.0), 0.0)  # LinuxCNC zeroed the offset at machine on
    r = cycle.commit()
    assert [e.name for e in r.events] == ["controller_on"]
    assert r.events[0].fields == {"was": "estop", "readback_um": 0.0}
    assert not r.status & (Status.ALARM | Status.READBACK_MISMATCH | Status.CONTROLLER_OFF)
    assert r.writes["offset"] == SLEW_UM_S * PERIOD_S  # one slew step from 0, never a jump
    previous = r.writes["offset"]
    for _ in range(10):
        t = clock.tick()
        cycle.plan(t, samples(t, 22.0), previous)
        r = cycle.commit()
        assert 0.0 < r.writes["offset"] - previous <= SLEW_UM_S * PERIOD_S + 1e-9
        assert not r.status & Status.ALARM
        previous = r.writes["offset"]


def test_a_ramp_to_zero_shutdown_is_done_while_the_machine_is_off() -> None:
    cycle, clock, held = _heated()
    cycle.begin_shutdown()
    t = clock.tick()
    plan = cycle.plan(t, samples(t, 22.0), held, controller_off="machine_off")
    assert plan.shutdown_done and "offset" not in plan.writes
    r = cycle.commit()
    assert r.shutdown_done and "offset" not in r.writes


def test_the_status_page_says_the_machine_is_off(tmp_path: Path) -> None:
    from compd.config.loader import load_config
    from compd.core.cycle import params_from_config
    from compd.faces.status import StatusBoard
    from tests.configs import MINIMAL

    path = tmp_path / "compd.toml"
    path.write_text(MINIMAL, encoding="utf-8")
    cfg = load_config(path)
    cycle, clock = Cycle(params_from_config(cfg), cfg.model), FakeClock()
    board = StatusBoard()
    for off in (None, "machine_off"):
        t = clock.tick()
        cycle.plan(t, {k: v for k, v in samples(t, 22.0).items() if k in cfg.channels},
                   0.0, controller_off=off)
        board.publish(cycle.commit(), cfg)
    assert board.snapshot["state"] == "holding"
    assert "machine is off or in E-stop" in board.snapshot["why"]


def test_the_status_word_is_the_health_s_own() -> None:
    """CONTROLLER_OFF comes from the one state machine's view, like every bit:
    a tracking output reads HOLDING and state "hold"; a fault keeps its own."""
    off = HealthView(policy=FaultState.OK, controller_off=True)
    assert status_word(off) == Status.CONTROLLER_OFF | Status.HOLDING
    assert recorded_state(off) == FaultState.HOLD
    ramp = HealthView(policy=FaultState.RAMP, alarm=True, controller_off=True)
    assert status_word(ramp) == Status.CONTROLLER_OFF | Status.RAMPING | Status.ALARM
    assert recorded_state(ramp) == FaultState.RAMP
