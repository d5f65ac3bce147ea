"""The tool direction (``[output.axes.tool]``) end to end over the real OPC UA and S7
drivers to their simulated SINUMERIK: a value alone, written to the channel's tool
temperature compensation (SD42960 ``$SC_TOOL_TEMP_COMP``, mm), beside the X axis's
line in the same write; refused on a controller that has no such setting."""

from __future__ import annotations

import copy
import tomllib
from pathlib import Path
from typing import Any

import pytest

from compd.config.loader import parse_config
from compd.core.cycle import Cycle
from compd.core.health import Cause
from compd.core.output import AxesStatus
from compd.core.params import params_from_config
from compd.errors import ConfigError
from compd.runtime.driver_setup import build_driver
from drivers.sim.opcua_server import OpcUaSimController
from drivers.sim.s7_server import S7SimController
from tests.compd.axes_helpers import axes_config_text, drive_cycle
from tests.compd.runtime.test_axes_opcua_s7 import SIMS, SLEW, Sim, _doc

#: the tool grows 2 µm per K of the column above 20 °C
TOOL_GAIN = 2.0


def _tool_doc(sim: Sim) -> dict[str, Any]:
    doc = _doc(sim, 20.0, 5.0, 6.5)
    axes = doc["output"]["axes"]
    model = copy.deepcopy(axes["x"]["model"])
    model["reference"] = {"column": 20.0}
    model["terms"] = [{"name": "tool", "inputs": {"column": TOOL_GAIN}, "a": ["1"],
                       "b": ["1"]}]
    axes["tool"] = {"value": sim.tool_comp["tool_comp_value"].model_dump(),
                    "value_limit_um": 100.0, "slew_um_s": SLEW, "model": model}
    return doc


async def _held(sim: Sim) -> float:
    if isinstance(sim, OpcUaSimController):
        return await sim.value("tool_comp_value")
    return await sim.read_back("tool_comp_value")


@pytest.mark.parametrize("protocol", sorted(SIMS))
async def test_the_tool_direction_takes_its_value(protocol: str, tmp_path: Path) -> None:
    make, _ = SIMS[protocol]
    sim = make()
    await sim.start()
    cfg = parse_config(_tool_doc(sim), tmp_path / "compd.toml")
    cycle = Cycle(params_from_config(cfg), cfg.model)
    driver = build_driver(cfg)
    try:
        await driver.connect()
        await sim.publish({"column": 30.0, "motor": 20.0, "bearing": 20.0, "ambient": 20.0})
        t = 0.0
        for _ in range(3):
            t += 600.0
            plan, row = await drive_cycle(driver, cycle, cfg, t)
        tool = row.axes["tool"]
        assert tool.cause == Cause.IN_FORCE and tool.in_force
        assert tool.value.confirmed == pytest.approx(20.0)  # 2 µm/K · 10 K
        assert "tool_comp_value" in plan.writes
        assert not {"tool_comp_slope", "tool_comp_reference"} & set(plan.writes)
        # the controller holds 0.020 mm, read back as 20 µm
        assert await _held(sim) == pytest.approx(20.0, abs=1e-3)
        # the axes word is X's alone (and LIFE): the tool direction has no bits
        word = int(plan.writes["axes_status"])
        assert word & ~int(AxesStatus.LIFE) == int(AxesStatus.X_IN_FORCE)
    finally:
        await driver.close()
        await sim.stop()


def test_the_tool_direction_is_refused_without_a_sinumerik(tmp_path: Path) -> None:
    doc = tomllib.loads(axes_config_text())
    model = _tool_doc(S7SimController())["output"]["axes"]["tool"]["model"]
    doc["output"]["axes"]["tool"] = {
        "value": {"kind": "holding", "address": 60, "type": "float32"},
        "value_limit_um": 100.0, "slew_um_s": SLEW, "model": model}
    with pytest.raises(ConfigError, match=r"output\.axes\.tool.*SD42960"):
        parse_config(doc, tmp_path / "compd.toml")


def test_the_opcua_sim_has_the_tool_node() -> None:
    sim = OpcUaSimController()
    assert sim.tool_comp["tool_comp_value"].node == \
        "ns=2;s=Machine.Channel.$SC_TOOL_TEMP_COMP"
    assert sim.tool_comp["tool_comp_value"].scale == 1000.0
