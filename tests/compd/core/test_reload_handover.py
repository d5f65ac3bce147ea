"""The reload's handover, pure: an unchanged model carries its filters over
exactly; another model restarts at the steady state for today's temperatures
while the output slews from what the controller holds; the fault policy's
hold timer survives a reload."""

from __future__ import annotations

import itertools
from pathlib import Path

import pytest

from compd.config.loader import load_config
from compd.core.cycle import Cycle, Row, params_from_config
from compd.core.faults import FaultState
from compd.core.output import Status
from compd.errors import ConfigError
from compd.runtime.reload import diff, handover, prepare
from compd.testing import FakeClock
from tests.compd.core.cycle_helpers import samples
from tests.configs import MINIMAL, write_config


def _warm(tmp_path: Path) -> tuple[Cycle, FakeClock, Path]:
    path = write_config(tmp_path, base=MINIMAL.replace("[output]", "[output]\nreadback = false"))
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
    state = old.models.model.export_state()
    new = handover(old, new_cfg, params_from_config(new_cfg), changes)
    assert new.models.model is not old.models.model and new.models.model.export_state() == state
    assert new.output.current_um == old.output.current_um
    assert new.sequence == old.sequence and new.heartbeat == old.heartbeat
    r = _step(new, clock)
    assert not any(e.name == "model_initialised" for e in r.events)  # no restart
    assert r.inputs_valid


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
    assert abs(r.stage_um - held) <= 1.0 * 1.0 + 1e-9  # ...reached at the slew limit


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


def test_a_lowered_limit_ramps_the_offset_written_into_it(tmp_path: Path) -> None:
    """21.55 µm or so written (read back), then a reload to limit_um = 20: the
    read-back is compd's own (no hold, no alarm), the offset ramps down to 20 at
    the slew limit, told by offset_beyond_limit and offset_within_limit."""
    path = write_config(tmp_path, base=MINIMAL)  # read-back on
    cfg = load_config(path)
    old, clock = Cycle(params_from_config(cfg), cfg.model), FakeClock()
    controller = 0.0
    for i in range(400):
        t = clock.tick()
        bearing = 20.0 if i < 3 else 22.5
        old.plan(t, {k: v for k, v in samples(t, bearing, 20.0).items() if k in cfg.channels},
                 controller)
        controller = old.commit().writes["offset"]
        if controller >= 21.55:
            break
    assert controller >= 21.55
    path.write_text(path.read_text().replace("limit_um = 100.0", "limit_um = 20.0"))
    new_cfg = load_config(path)
    new = handover(old, new_cfg, params_from_config(new_cfg), diff(cfg, new_cfg))
    written: list[float] = [controller]
    names: list[str] = []
    for _ in range(6):
        t = clock.tick()
        new.plan(t, {k: v for k, v in samples(t, 22.5, 20.0).items() if k in cfg.channels},
                 controller)
        r = new.commit()
        names += [str(e.name) for e in r.events]
        assert not r.status & (Status.OFFSET_HELD | Status.ALARM) and r.state == "ok"
        controller = r.writes["offset"]
        written.append(controller)
    assert "readback_out_of_range" not in names
    assert names.count("offset_beyond_limit") == 1 and names.count("offset_within_limit") == 1
    steps = [a - b for a, b in itertools.pairwise(written)]
    assert all(0.0 <= s <= 1.0 + 1e-9 for s in steps)  # down, never faster than 1 µm/s
    assert written[1] > 20.0 and written[-1] == 20.0


def test_moving_the_offset_on_the_same_controller_is_refused_by_name(tmp_path: Path) -> None:
    """The old address would keep its last offset under a live heartbeat; a moved
    heartbeat (the old one stops counting: compd gone for a PLC reading it), a
    rescaled offset at the same address (read-back judges it) and another endpoint
    (another controller) are reloads like any other."""
    text = MINIMAL.replace("[output]", '[output]\nheartbeat = { kind = "holding", address = 2, '
                        'type = "uint16" }')
    path = write_config(tmp_path, base=text)
    old = load_config(path)
    path.write_text(text.replace('offset = { kind = "holding", address = 0,',
                                 'offset = { kind = "holding", address = 20,'))
    with pytest.raises(ConfigError) as info:
        prepare(old)
    assert info.value.key == "output.offset"
    assert "unit1/holding/0:float32" in info.value.reason and "restart compd" in info.value.reason
    for allowed in (text.replace("address = 2,", "address = 22,"),
                    text.replace('address = 0, type = "float32" }',
                                 'address = 0, type = "int32", scale = 0.01 }'),
                    text.replace("127.0.0.1:5020", "127.0.0.1:5021")
                        .replace('offset = { kind = "holding", address = 0,',
                                 'offset = { kind = "holding", address = 20,')):
        path.write_text(allowed)
        new, _ = prepare(old)
        assert new.raw.output == load_config(path).raw.output


@pytest.mark.parametrize("start_recording", [True, False])
def test_a_reload_never_switches_recorder_only_on_or_off(
        tmp_path: Path, start_recording: bool) -> None:
    """Recorder only writes nothing: a reload that would start writing (or stop, leaving
    the last offset in the controller) is refused; a restart decides it."""
    writing = MINIMAL
    recording = MINIMAL.replace("[output]", "[output]\nenabled = false")
    path = write_config(tmp_path, base=recording if start_recording else writing)
    old = load_config(path)
    assert old.recorder_only is start_recording
    path.write_text(writing if start_recording else recording)
    with pytest.raises(ConfigError) as info:
        prepare(old)
    assert info.value.key == "output.enabled" and "restart compd" in info.value.reason
    # a recorder-only config reloads as any other (nothing to keep in place)
    path.write_text(recording)
    if start_recording:
        new, _ = prepare(old)
        assert new.recorder_only and not new.outputs
