"""An axis's model state is taken back (a restart from the checkpoint, a reload)
only by the same model: another value or slope model starts at the steady state
of today's inputs, as the offset's model does, never in the state of another."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from compd.config.loader import load_config
from compd.core.cycle import Cycle
from compd.core.params import params_from_config
from compd.core.restore import restore_arguments
from compd.testing import FakeClock
from tests.compd.axes_helpers import write_axes_config
from tests.compd.cycle_helpers import sp2
from tests.compd.test_cycle_axes import axis_params, inputs, static


def _run(cycle: Cycle, n: int) -> None:
    clock = FakeClock(period_s=1.0)
    for _ in range(n):
        t = clock.tick()
        cycle.plan(t, inputs(t))
        cycle.commit()


def _restarted(state: dict[str, Any], **over: Any) -> Cycle:
    args = restore_arguments(state, fresh=True, same_model=True, age_s=1.0)
    return Cycle(axis_params(**over), sp2(), **args)


def test_only_the_same_axis_model_takes_its_state_back() -> None:
    first = Cycle(axis_params(value_sha256="a", slope_sha256="b"), sp2())
    _run(first, 5)
    state = first.export_state()
    x = state["axes"]["x"]
    assert x["value_model_sha256"] == "a" and x["slope_model_sha256"] == "b"
    same = _restarted(state, value_sha256="a", slope_sha256="b")
    axis = same.axes.axes[0]
    assert axis.value.models is not None and axis.value.models.init_mode == "restored"
    assert axis.slope.models is not None and axis.slope.models.init_mode == "restored"
    # another value model (other gains): its own steady state; the slope's is the same
    other = _restarted(state, value_model=static("value", {"nut": 4.0}),
                       value_sha256="c", slope_sha256="b")
    axis = other.axes.axes[0]
    assert axis.value.models is not None and axis.value.models.init_mode == "steady_state"
    assert axis.slope.models is not None and axis.slope.models.init_mode == "restored"
    # the confirmed line is still where the controller holds it: the stage slews from it
    assert axis.value.stage.current_um == first.axes.axes[0].value.stage.confirmed_um


def test_the_config_names_each_axis_model(tmp_path: Path) -> None:
    cfg = load_config(write_axes_config(tmp_path))
    (x,) = params_from_config(cfg).axes
    assert len(x.value_sha256) == 64 and len(x.slope_sha256) == 64
    assert x.value_sha256 != x.slope_sha256
    again = load_config(write_axes_config(tmp_path, kc=4.0))  # another value model
    (y,) = params_from_config(again).axes
    assert y.value_sha256 != x.value_sha256 and y.slope_sha256 == x.slope_sha256
