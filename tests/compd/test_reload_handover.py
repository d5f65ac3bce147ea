"""The reload's handover, pure: an unchanged model carries its filters over
exactly; another model restarts at the steady state for today's temperatures
while the output slews from what the controller holds; the fault policy's
hold timer survives a reload."""

from __future__ import annotations

from pathlib import Path

from compd.config.loader import load_config
from compd.core.cycle import Cycle, Row, params_from_config
from compd.core.faults import FaultState
from compd.runtime.reload import diff, handover
from compd.testing import FakeClock

from .cycle_helpers import samples
from .test_config import BASE


def _cfg(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "compd.toml"
    p.write_text(text, encoding="utf-8")
    return p


def _warm(tmp_path: Path) -> tuple[Cycle, FakeClock, Path]:
    path = _cfg(tmp_path, BASE.replace("[output]", "[output]\nreadback = false"))
    cfg = load_config(path)
    cycle = Cycle(params_from_config(cfg), cfg.model)
    clock = FakeClock()
    for i in range(120):  # first start at 20 °C (the references), then the spindle warms
        t = clock.tick()
        bearing = 20.0 if i < 3 else min(24.0, 20.0 + 0.4 * (i - 3))
        cycle.plan(t, {k: v for k, v in samples(t, bearing, 20.0).items()
                       if k in cfg.channels})
        cycle.commit()
    assert cycle.output.current_um > 5.0
    return cycle, clock, path


def _step(cycle: Cycle, clock: FakeClock, bearing: float = 24.0) -> Row:
    t = clock.tick()
    cycle.plan(t, {k: v for k, v in samples(t, bearing, 20.0).items()
                   if k in ("bearing", "ambient")})
    return cycle.commit()


def test_unchanged_model_carries_its_filters_over(tmp_path: Path) -> None:
    old, clock, path = _warm(tmp_path)
    old_cfg = load_config(path)
    path.write_text(path.read_text().replace("slew_um_s = 1.0", "slew_um_s = 0.8"))
    new_cfg = load_config(path)
    changes = diff(old_cfg, new_cfg)
    assert not changes.model and not changes.controller
    state = old.model.export_state()
    new = handover(old, new_cfg, params_from_config(new_cfg), changes)
    assert new.model is not old.model and new.model.export_state() == state
    assert new.output.current_um == old.output.current_um
    assert new.sequence == old.sequence and new.heartbeat == old.heartbeat
    r = _step(new, clock)
    assert not any(e.name == "model_initialised" for e in r.events)  # no restart
    assert r.complete


def test_the_controller_state_inputs_are_a_new_driver(tmp_path: Path) -> None:
    """output.machine_on/estop are read by the driver like channels: adding one
    needs a driver that knows its address."""
    _, _, path = _warm(tmp_path)
    old_cfg = load_config(path)
    path.write_text(path.read_text().replace(
        "[output]", '[output]\nmachine_on = { kind = "input", address = 9, type = "uint16" }'))
    new_cfg = load_config(path)
    assert diff(old_cfg, new_cfg).controller and "machine_on" in new_cfg.states


def test_another_model_restarts_at_steady_state_and_slews(tmp_path: Path) -> None:
    old, clock, path = _warm(tmp_path)
    old_cfg = load_config(path)
    held = old.output.current_um
    path.write_text(path.read_text().replace('file = "sp2"', 'file = "sp3"'))
    new_cfg = load_config(path)
    changes = diff(old_cfg, new_cfg)
    assert changes.model
    new = handover(old, new_cfg, params_from_config(new_cfg), changes)
    assert new.output.current_um == held  # what the controller holds
    r = _step(new, clock)
    (init,) = [e for e in r.events if e.name == "model_initialised"]
    assert init.fields["mode"] == "steady_state"
    assert r.model_um is not None and abs(r.model_um - held) > 1.0  # another value...
    assert abs(r.offset_um - held) <= 1.0 * 1.0 + 1e-9  # ...reached at the slew limit


def test_a_reload_keeps_the_fault_hold_timer(tmp_path: Path) -> None:
    old, clock, path = _warm(tmp_path)
    for _ in range(40):  # the read fails: hold (hold_s 60 by default)
        old.plan(clock.tick(), None)
    assert old.health.policy == FaultState.HOLD
    new_cfg = load_config(path)
    new = handover(old, new_cfg, params_from_config(new_cfg), diff(load_config(path), new_cfg))
    states = [new.plan(clock.tick(), None).state for _ in range(25)]
    # 40 s held before the reload + 25 after: the ramp begins at 60 s, not 60 s after it
    assert FaultState.RAMP in states
