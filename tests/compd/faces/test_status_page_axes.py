"""The operator page shows each ``[output.axes]`` axis's line (in force or not and
why, its value and slope, what the controller holds when it differs, its
reference position) in a real headless browser, from a document the status
board built from the cycle's report; a page without axes shows no axes table."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

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

_AXES = ('return [...document.querySelectorAll("#m0 table.axes tr")]'
         '.map(tr => [...tr.cells].map(td => td.textContent))')
_SHOWN = ('return [document.querySelector("#m0 table.axes").style.display,'
          ' document.querySelector("#m0 .axeslabel").textContent]')


def _documents(tmp_path: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """/status.json with X in force, then with X's nut invalid (held)."""
    cfg = load_config(write_axes_config(tmp_path, period_s=1.0, time_scale=1.0,
                                        value_slew=5.0, slope_slew=5.0))
    cycle = Cycle(dataclasses.replace(params_from_config(cfg), readback=False), cfg.model)
    board, clock = StatusBoard(), FakeClock(period_s=1.0)
    docs = []
    for nut in (24.0, math.nan):
        for _ in range(12):
            t = clock.tick()
            temps = {"nut": nut, "screw_bearing": 24.0, "column": 22.0, "ambient": 20.0}
            cycle.plan(t, {n: Sample(v, t) for n, v in temps.items()})
            row = cycle.commit()
        board.publish(row, cfg)
        docs.append(board.snapshot)
    return docs[0], docs[1]


@pytest.mark.skipif(browser_missing() is not None, reason=str(browser_missing()))
def test_the_page_shows_each_axis_line(tmp_path: Path) -> None:
    on, held = _documents(tmp_path)
    assert on["axes"]["x"]["in_force"] and not held["axes"]["x"]["in_force"]
    without = {k: v for k, v in on.items() if k != "axes"}
    seen = {}
    with headless_chromium() as browser:
        for name, doc in (("on", on), ("held", held), ("without", without)):
            page = tmp_path / f"{name}.html"
            page.write_text(render_page(doc, 5.0), encoding="utf-8")
            browser.get(page.as_uri())
            browser.wait_for('return document.querySelector("#m0 .state") !== null')
            seen[name] = browser.script(_AXES), browser.script(_SHOWN)
    rows, shown = seen["on"]
    assert shown == ["", "Axes"]
    # 3·2 + 1.5·4 = 12 µm; 5·4 + 6.5·4 = 46 µm/m, at the reference position 0 mm
    assert rows == [["X", "in force", "ok", "12.00 µm", "46.00 µm/m", "at 0.0 mm"]]
    rows, _ = seen["held"]
    assert rows[0][:3] == ["X", "not in force", "hold [inputs_invalid]"]
    assert rows[0][3:5] == ["12.00 µm", "46.00 µm/m"]  # held where it was
    rows, shown = seen["without"]
    assert rows == [] and shown[0] == "none"
