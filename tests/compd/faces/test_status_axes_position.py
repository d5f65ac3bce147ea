"""/status.json shows, for an axis written as an offset at its position, the position
the offset was evaluated at and the offset sent; an axis with the line's parameters
has neither key; the operator page shows them in the axis's row."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from compd.config.loader import load_config
from compd.core.cycle import Cycle
from compd.core.params import params_from_config
from compd.faces.status import StatusBoard
from compd.faces.status_page import render_page
from compd.testing import FakeClock
from drivers.base import Sample
from tests.compd.axes_helpers import write_axes_config
from tests.compd.faces.webdriver import browser_missing, headless_chromium
from tests.compd.runtime.test_axes_position_modbus import positional_config


def _axis(cfg_path: Path, position: float | None) -> dict[str, object]:
    cfg = load_config(cfg_path)
    cycle = Cycle(dataclasses.replace(params_from_config(cfg), readback=False), cfg.model)
    board, clock = StatusBoard(), FakeClock(period_s=1.0)
    for _ in range(3):
        t = clock.tick()
        temps = {"nut": 24.0, "screw_bearing": 24.0, "column": 22.0, "ambient": 20.0}
        if position is not None:
            temps["x_pos"] = position
        cycle.plan(t, {n: Sample(v, t) for n, v in temps.items()})
        row = cycle.commit()
    board.publish(row, cfg)
    axes = board.snapshot["axes"]
    assert isinstance(axes, dict)
    return dict(axes["x"])


def test_status_json_shows_the_position_and_the_offset(tmp_path: Path) -> None:
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    x = _axis(positional_config(tmp_path / "a", "modbus://127.0.0.1:5020", period_s=1.0,
                                time_scale=1.0, value_slew=5.0, slope_slew=5.0), 800.0)
    assert x["position_mm"] == 800.0
    assert x["offset_um"] == pytest.approx(
        x["value_um"] + x["slope_um_m"] * 0.8)  # type: ignore[operator]
    line = _axis(write_axes_config(tmp_path / "b", period_s=1.0, time_scale=1.0,
                                   value_slew=5.0, slope_slew=5.0), None)
    assert "position_mm" not in line and "offset_um" not in line


@pytest.mark.skipif(browser_missing() is not None, reason=str(browser_missing()))
def test_the_page_shows_the_position_and_the_offset(tmp_path: Path) -> None:
    (tmp_path / "a").mkdir()
    cfg = positional_config(tmp_path / "a", "modbus://127.0.0.1:5020", period_s=1.0,
                            time_scale=1.0, value_slew=5.0, slope_slew=5.0)
    x = _axis(cfg, 800.0)
    doc = {"axes": {"x": x}, "state": "ok", "offset_um": 0.0, "channels": []}
    page = tmp_path / "page.html"
    page.write_text(render_page(doc, 5.0), encoding="utf-8")
    with headless_chromium() as browser:
        browser.get(page.as_uri())
        browser.wait_for('return document.querySelector("#m0 .state") !== null')
        rows = browser.script('return [...document.querySelectorAll("#m0 table.axes tr")]'
                              '.map(tr => [...tr.cells].map(td => td.textContent))')
    assert rows[0][0] == "X"
    assert rows[0][-1] == f"{x['offset_um']:.2f} µm at 800.0 mm"
