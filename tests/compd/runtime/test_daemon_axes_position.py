"""The daemon with an axis written as an offset at its position over an in-memory
controller: the position is read with the temperatures every cycle, the offset at it
goes out in the cycle's one write, and the checkpoint keeps the offset and the
position it was written at, so a restart resumes from it without a jump."""

from __future__ import annotations

from pathlib import Path

from compd.config.loader import load_config
from compd.runtime.checkpoint import load_checkpoint
from compd.testing import MemoryDriver
from tests.compd.runtime.test_axes_position_modbus import positional_config
from tests.compd.runtime.test_daemon_axes import _run

OUTPUTS = ("offset", "heartbeat", "status", "axes_status", "x_comp_offset")


async def test_the_daemon_writes_the_offset_at_the_position_and_resumes_it(
        tmp_path: Path) -> None:
    cfg = load_config(positional_config(tmp_path, "modbus://127.0.0.1:5020", period_s=1.0,
                                        time_scale=1.0, timeout_s=0.2, value_slew=0.5,
                                        slope_slew=0.25))
    temps = {"nut": 24.0, "screw_bearing": 24.0, "column": 22.0, "ambient": 20.0,
             "x_pos": 800.0}
    driver = MemoryDriver(temps, OUTPUTS)
    await _run(cfg, driver, 8)
    written = driver.outputs["x_comp_offset"]
    saved = load_checkpoint(cfg.state_dir / "checkpoint.json")
    assert saved is not None
    axis = saved["state"]["axes"]["x"] if "state" in saved else saved["axes"]["x"]
    value, slope = axis["value"], axis["slope"]
    # the line at 800 mm (reference 0), as the models' stages stand
    assert slope > 0.0 and written == value + slope * 0.8
    assert axis["position_mm"] == 800.0 and axis["offset_um"] == written
    # the read-back of the offset at start is the line the checkpoint held, not a
    # foreign value: the value's stage goes on from it
    assert not {"x_comp_value", "x_comp_slope"} & {k for w in driver.writes for k in w}
    # a restart: from the checkpoint's offset at its position, at most the rates' step
    again = MemoryDriver(temps, OUTPUTS)
    again.outputs["x_comp_offset"] = written
    before = len(again.writes)
    await _run(load_config(cfg.path), again, 1)
    first = again.writes[before]["x_comp_offset"]
    assert written <= first <= written + 0.5 * 2 + 0.25 * 2 * 0.8 + 1e-9
