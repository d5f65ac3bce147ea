"""The axes word (`compd.core.output.AxesStatus`, ``[output] axes_status``): per
axis in force, alarm, holding and ramping, and a life bit, written in the cycle's
one write; the heartbeat keeps its meaning (the offset's model's valid cycle)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import pytest

from compd.config.loader import load_config
from compd.core.cycle import Cycle, Outcome
from compd.core.output import AxesStatus as A
from compd.core.output import Status
from compd.core.params import params_from_config
from compd.errors import ConfigError
from compd.testing import FakeClock
from tests.compd.axes_helpers import axes_config_text, write_axes_config
from tests.compd.cycle_helpers import HOLD_S, sp2
from tests.compd.test_cycle_axes import axis_params, inputs


def _cycle() -> Cycle:
    # a slope limit the model stays inside: the line in force is the model's
    p = dataclasses.replace(axis_params(slope_limit_um_m=50.0), axes_status_name="axes_status")
    return Cycle(p, sp2())


def _run(cycle: Cycle, clock: FakeClock, n: int, **over: float) -> list[tuple[int, int, int]]:
    """(heartbeat, status, axes word) written in each of `n` cycles."""
    out = []
    for _ in range(n):
        t = clock.tick()
        plan = cycle.plan(t, inputs(t, **over))
        cycle.commit()
        w = plan.writes
        out.append((int(w["heartbeat"]), int(w["status"]), int(w["axes_status"])))
    return out


def test_an_axis_is_in_force_once_the_controller_confirmed_its_line() -> None:
    cycle, clock = _cycle(), FakeClock(period_s=1.0)
    words = [w for _, _, w in _run(cycle, clock, 3)]
    # the first write carries no confirmed line yet; from the second on it is in force
    assert not words[0] & A.X_IN_FORCE
    assert all(w & A.X_IN_FORCE for w in words[1:])
    # one axis configured: no other axis's bit, and no alarm, hold or ramp
    assert all(w & ~(A.X_IN_FORCE | A.LIFE) == 0 for w in words[1:])
    # LIFE toggles in every word
    assert [bool(w & A.LIFE) for w in words] == [True, False, True]
    # a refused write: the next word does not claim the line in force
    t = clock.tick()
    cycle.plan(t, inputs(t))
    cycle.commit(Outcome.failed("x_comp_value", reason="refused"))
    t = clock.tick()
    assert not int(cycle.plan(t, inputs(t)).writes["axes_status"]) & A.X_IN_FORCE
    cycle.commit()


def test_an_invalid_axis_input_clears_its_bit_while_the_heartbeat_goes_on() -> None:
    cycle, clock = _cycle(), FakeClock(period_s=1.0)
    _run(cycle, clock, 5)
    held = _run(cycle, clock, int(HOLD_S) - 2, nut=math.nan)
    # the offset's model reads no nut: its cycle is valid, the heartbeat advances
    beats = [hb for hb, _, _ in held]
    assert beats == list(range(beats[0], beats[0] + len(beats)))
    assert all(st & Status.OK for _, st, _ in held)
    # X holds: not in force, HOLDING, no alarm yet
    assert all(w & A.X_HOLDING and not w & (A.X_IN_FORCE | A.X_ALARM) for _, _, w in held)
    # past hold_s X ramps to 0, alarmed; Z is still OK
    _, st, w = _run(cycle, clock, 5, nut=math.nan)[-1]
    assert w & A.X_RAMPING and w & A.X_ALARM and not w & A.X_IN_FORCE
    assert st & Status.OK
    # the input back: X tracks again, in force from the next confirmed write
    words = [w for _, _, w in _run(cycle, clock, 3)]
    assert words[-1] & A.X_IN_FORCE and not words[-1] & (A.X_ALARM | A.X_RAMPING)


def test_an_invalid_offset_input_stalls_the_heartbeat_not_the_axis() -> None:
    cycle, clock = _cycle(), FakeClock(period_s=1.0)
    _run(cycle, clock, 5)
    got = _run(cycle, clock, 6, bearing=math.nan)
    # the heartbeat stays (the offset's inputs are invalid) and the status word holds
    assert len({hb for hb, _, _ in got}) == 1
    assert all(st & Status.HOLDING and not st & Status.OK for _, st, _ in got)
    # the axes word still changes every cycle (LIFE) and X stays in force
    assert [bool(w & A.LIFE) for _, _, w in got] == [bool(i % 2) for i in range(6)] or \
        [bool(w & A.LIFE) for _, _, w in got] == [not (i % 2) for i in range(6)]
    assert all(w & A.X_IN_FORCE for _, _, w in got)


def test_the_axes_word_is_configured_and_range_checked(tmp_path: Path) -> None:
    cfg = load_config(write_axes_config(tmp_path))
    assert params_from_config(cfg).axes_status_name == "axes_status"
    assert "axes_status" in cfg.outputs
    p = tmp_path / "bad.toml"
    # an address that cannot hold every bit
    p.write_text(axes_config_text().replace(
        'axes_status = { kind = "holding", address = 4, type = "uint16" }',
        'axes_status = { kind = "holding", address = 4, type = "uint16", scale = 0.1 }'),
        encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_config(p)
    assert info.value.key == "output.axes_status"
    # without [output.axes] there is nothing for it to say
    text = axes_config_text()
    p.write_text(text[:text.index("[output.axes.x]")] + text[text.index("[faults]"):],
                 encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_config(p)
    assert info.value.key == "output.axes_status"
