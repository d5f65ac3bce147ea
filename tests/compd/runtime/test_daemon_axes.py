"""The daemon with ``[output.axes.x]`` over an in-memory controller: the axis's
parameters written in the cycle's one write, its state in the checkpoint, and a
restart that resumes from the checkpoint without a jump."""

from __future__ import annotations

from pathlib import Path

from compd.config.loader import load_config
from compd.core.output import AxesStatus
from compd.runtime.checkpoint import load_checkpoint
from compd.runtime.daemon import Daemon
from compd.testing import MemoryDriver
from tests.compd.axes_helpers import write_axes_config
from tests.harness import stepped_daemon

OUTPUTS = ("offset", "heartbeat", "status", "axes_status", "x_comp_value", "x_comp_slope",
           "x_comp_reference")


async def _run(cfg, driver: MemoryDriver, cycles: int) -> Daemon:  # type: ignore[no-untyped-def]
    async with stepped_daemon(cfg, driver=driver) as run:
        await run.until(lambda: run.daemon.loop.cycles >= cycles)
        assert await run.stop() == 0
    return run.daemon


async def test_the_daemon_writes_the_axis_and_resumes_it_after_a_restart(
        tmp_path: Path) -> None:
    cfg = load_config(write_axes_config(tmp_path, period_s=1.0, time_scale=1.0,
                                        timeout_s=0.2, value_slew=0.5, slope_slew=0.25))
    temps = {"nut": 24.0, "screw_bearing": 24.0, "column": 22.0, "ambient": 20.0}
    driver = MemoryDriver(temps, OUTPUTS)
    await _run(cfg, driver, 8)
    # 3·2 + 1.5·4 = 12 µm at 0.5 µm/s; 5·4 + 6.5·4 = 46 µm/m at 0.25 µm/m/s
    value, slope = driver.outputs["x_comp_value"], driver.outputs["x_comp_slope"]
    assert 3.0 <= value < 12.0 and 1.5 <= slope < 46.0
    assert driver.outputs["x_comp_reference"] == 0.0
    # the axes word beside them: X in force, the life bit toggling from write to write
    words = [int(w["axes_status"]) for w in driver.writes if "axes_status" in w]
    assert words[-1] & AxesStatus.X_IN_FORCE
    assert {w & AxesStatus.LIFE for w in words[-2:]} == {0, AxesStatus.LIFE}
    saved = load_checkpoint(cfg.state_dir / "checkpoint.json")
    assert saved is not None
    axis = saved["state"]["axes"]["x"] if "state" in saved else saved["axes"]["x"]
    assert (axis["value"], axis["slope"]) == (value, slope)
    # a restart: the stage resumes from the confirmed line, moving at most its rate
    again = MemoryDriver(temps, OUTPUTS)
    again.outputs.update({"x_comp_value": value, "x_comp_slope": slope})
    before = len(again.writes)
    await _run(load_config(cfg.path), again, 1)
    first = again.writes[before]
    assert abs(first["x_comp_value"] - value) <= 0.5 * 2 + 1e-9
    assert abs(first["x_comp_slope"] - slope) <= 0.25 * 2 + 1e-9
    assert first["x_comp_value"] >= value  # from the checkpoint's line, not from 0
