"""A reload carries each ``[output.axes]`` axis over: its hold timer goes on
toward the ramp (a reload never postpones it), its line in force stays in force
and the axes word's life bit toggles on without a repeat."""

from __future__ import annotations

import math
from pathlib import Path

from compd.config.loader import LoadedConfig, load_config
from compd.core.cycle import Cycle
from compd.core.faults import FaultState
from compd.core.output import AxesStatus
from compd.core.params import params_from_config
from compd.core.plan import Plan
from compd.runtime.reload import diff, handover
from compd.testing import FakeClock
from drivers.base import Sample
from tests.compd.axes_helpers import axes_config_text

TEMPS = {"nut": 24.0, "screw_bearing": 24.0, "column": 22.0, "ambient": 20.0}


def _cfg(tmp_path: Path) -> LoadedConfig:
    path = tmp_path / "compd.toml"
    path.write_text(axes_config_text(period_s=1.0, time_scale=1.0, timeout_s=0.2,
                                     hold_s=60.0).replace("[output]\n",
                                                          "[output]\nreadback = false\n"),
                    encoding="utf-8")
    return load_config(path)


def _plan(cycle: Cycle, t: float, nut: float = 24.0) -> Plan:
    temps = {**TEMPS, "nut": nut}
    plan = cycle.plan(t, {n: Sample(v, t) for n, v in temps.items()})
    cycle.commit()
    return plan


def test_a_reload_keeps_an_axis_hold_timer_and_its_line_in_force(tmp_path: Path) -> None:
    cfg = _cfg(tmp_path)
    old, clock = Cycle(params_from_config(cfg), cfg.model), FakeClock(period_s=1.0)
    words = [int(_plan(old, clock.tick()).writes["axes_status"]) for _ in range(5)]
    assert words[-1] & AxesStatus.X_IN_FORCE
    # a reload that changes nothing of the axis: in force on, the life bit toggles on
    new = handover(old, cfg, params_from_config(cfg), diff(cfg, _cfg(tmp_path)))
    word = int(_plan(new, clock.tick()).writes["axes_status"])
    assert word & AxesStatus.X_IN_FORCE
    assert (word ^ words[-1]) & AxesStatus.LIFE
    # the nut fails: X holds 40 s, then a reload, then 25 s more
    for _ in range(40):
        _plan(new, clock.tick(), nut=math.nan)
    assert new.axes.axes[0].health.policy == FaultState.HOLD
    again = handover(new, cfg, params_from_config(cfg), diff(cfg, _cfg(tmp_path)))
    states = []
    for _ in range(25):
        plan = _plan(again, clock.tick(), nut=math.nan)
        states.append(again.axes.axes[0].health.policy)
    # 40 s held before the reload + 25 after: X ramps at 60 s, not 60 s after the reload
    assert FaultState.RAMP in states
    assert int(plan.writes["axes_status"]) & AxesStatus.X_RAMPING
