"""What the status page shows: °C rather than degC, rpm without
decimals, y-axis ticks at nice numbers labelled with the step's decimals, the
last time label inside the canvas, times on the 24-hour clock, the ± limit in
the legend only as drawn (else its value, off scale), rounded numbers in the
alarm list, and while the controller does not answer, what really happens
(nothing can be written) rather than "the offset ramps to 0". The page's
script runs in node (the browser test needs chromium, often absent) with a
recording stand-in for the canvas."""

from __future__ import annotations

import itertools
import json
import math
import shutil
import subprocess

import pytest

from compd.core.faults import FaultState
from compd.core.health import Cause
from compd.faces.status import StatusBoard, operator_state
from compd.faces.status_page import _SCRIPT

NODE = shutil.which("node")
needs_node = pytest.mark.skipif(NODE is None, reason="node absent: apt-get install nodejs")


def _node(test_code: str) -> object:
    """Run the page's functions (everything but the start-up line) and `test_code`,
    which prints one JSON value."""
    assert NODE is not None
    script = "const REFRESH_S = 5;\n" + _SCRIPT.rsplit("show(FIRST);", 1)[0] + test_code
    r = subprocess.run([NODE, "-e", script], capture_output=True, text=True, timeout=60,
                       check=False)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


@needs_node
def test_units_are_shown_as_an_operator_reads_them() -> None:
    got = _node('console.log(JSON.stringify([unit("degC"), unit("rpm"), unit("um"), '
                'fmt(6600, digits("rpm")), fmt(23.456, digits("degC"))]));')
    assert got == ["°C", "rpm", "µm", "6600", "23.46"]


_CANVAS = """
const calls = [];
const g = {font: "", fillStyle: "", strokeStyle: "", lineWidth: 1, textAlign: "left",
  clearRect(){}, beginPath(){}, moveTo(){}, lineTo(){}, stroke(){}, setLineDash(){},
  measureText(text){ return {width: 7 * String(text).length}; },
  fillText(text, x, y){ calls.push({text: String(text), x: x, y: y, align: this.textAlign,
                                    color: this.fillStyle}); }};
const cv = {clientWidth: 800, clientHeight: 260, getContext: () => g};
"""


@needs_node
@pytest.mark.parametrize("span", [(-2.0, 15.0), (0.0, 0.3), (-120.0, 180.0), (3.0, 3.2),
                                  (-4.0, 5.0)])
def test_the_y_axis_ticks_are_nice_numbers(span: tuple[float, float]) -> None:
    lo, hi = span
    h = {"wall_s": [1000.0 + 60 * i for i in range(11)],
         "offset_um": [lo + (hi - lo) * i / 10 for i in range(11)],
         "model_um": [lo + (hi - lo) * i / 10 for i in range(11)]}
    calls = _node(_CANVAS + f"plot(cv, {json.dumps(h)}, 200);"
                  "console.log(JSON.stringify(calls.filter(c => c.x === 5 && c.text !== "
                  '"\\u00b5m").map(c => c.text)));')
    assert isinstance(calls, list) and len(calls) >= 3
    values = [float(t) for t in calls]
    steps = {round(b - a, 9) for a, b in itertools.pairwise(values)}
    assert len(steps) == 1  # evenly spaced
    [step] = steps
    mantissa = step / 10 ** math.floor(math.log10(step))
    assert round(mantissa, 6) in (1.0, 2.0, 2.5, 5.0), calls
    for v in values:  # each tick a multiple of the step
        assert abs(v / step - round(v / step)) < 1e-6, calls


@needs_node
def test_the_last_time_label_ends_inside_the_canvas() -> None:
    h = {"wall_s": [1000.0 + 60 * i for i in range(11)], "offset_um": [1.0] * 11,
         "model_um": [1.0] * 11}
    calls = _node(_CANVAS + f"plot(cv, {json.dumps(h)}, 200);"
                  "console.log(JSON.stringify(calls.filter(c => c.y === 260 - 6)));")
    assert isinstance(calls, list) and len(calls) == 5
    last = calls[-1]
    assert last["align"] == "right" and last["x"] <= 800  # right-aligned at the edge
    assert calls[0]["align"] == "left"


def test_alarm_details_are_rounded() -> None:
    board = StatusBoard()
    board.alarm("channel_invalid", "warning", {"invalid_for_s": 60.997285639999745,
                                               "channel": "bearing", "count": 3},
                wall_s=1000.0)
    [alarm] = board._alarms
    assert alarm["detail"] == {"invalid_for_s": "61", "channel": "bearing", "count": "3"}


def test_an_alarm_is_stamped_with_the_daemons_clock_not_the_boards() -> None:
    """The board keeps no clock: the journal (the runtime's, with the daemon's
    injected clock) says when a warning happened."""
    import structlog

    from compd.core.events import Event, EventName
    from compd.runtime.clock import Clock
    from compd.runtime.journal import Journal

    board = StatusBoard()
    journal = Journal(structlog.get_logger("t"), board,
                      Clock(mono=lambda: 5.0, wall=lambda: 1234.5))
    journal.events([Event(EventName.CHANNEL_INVALID, {"channel": "bearing"})])
    journal.alarm("cycle_broken", "error", {"error": "x"})
    assert [(a["event"], a["wall_s"]) for a in board._alarms] == [
        ("channel_invalid", 1234.5), ("cycle_broken", 1234.5)]


@pytest.mark.parametrize("state", [FaultState.HOLD, FaultState.RAMP])
def test_an_unreachable_controller_is_said_as_it_is(state: FaultState) -> None:
    word, why = operator_state(state, Cause.CONTROLLER_NOT_ANSWERING,
                               {"bearing": "read_failed", "ambient": "read_failed"})
    assert word == ("ramping" if state is FaultState.RAMP else "holding")
    assert "ramps to 0" not in why
    assert "does not answer" in why and "nothing can be read or written" in why
    # an invalid reading with the controller answering: still the ramp
    _, why = operator_state(FaultState.RAMP, Cause.INPUTS_INVALID,
                            {"bearing": "out_of_range", "ambient": None})
    assert "ramps to 0" in why


@needs_node
def test_a_step_of_2_5_is_labelled_with_its_decimal() -> None:
    h = {"wall_s": [1000.0 + 60 * i for i in range(11)],
         "offset_um": [-4.0 + 0.9 * i for i in range(11)], "model_um": [0.0] * 11}
    calls = _node(_CANVAS + f"plot(cv, {json.dumps(h)}, 200);"
                  "console.log(JSON.stringify(calls.filter(c => c.x === 5 && c.text !== "
                  '"\\u00b5m").map(c => c.text)));')
    assert calls == ["-2.5", "0.0", "2.5", "5.0"]  # not 5, 3, 0, -3 on even gridlines


@needs_node
def test_times_are_on_the_24_hour_clock() -> None:
    # 15:04:05 local time today, whatever the machine's zone and locale
    got = _node("const d = new Date(); d.setHours(15, 4, 5, 0);"
                "console.log(JSON.stringify([clock(d.getTime() / 1000),"
                " stamp(d.getTime() / 1000)]));")
    assert isinstance(got, list)
    assert got[0] == "15:04:05"
    assert got[1].endswith(" 15:04:05") and "PM" not in got[1]


def _legend(limit: float, top: float) -> list[str]:
    h = {"wall_s": [1000.0 + 60 * i for i in range(11)],
         "offset_um": [top * i / 10 for i in range(11)], "model_um": [top * i / 10
                                                                   for i in range(11)]}
    calls = _node(_CANVAS + f"plot(cv, {json.dumps(h)}, {limit});"
                  "console.log(JSON.stringify(calls.filter(c => c.y === 12 && c.x !== 5)));")
    assert isinstance(calls, list)
    # right-aligned from the canvas's right edge leftwards, none overlapping
    spans = sorted((c["x"] - 7 * len(c["text"]), c["x"]) for c in calls)
    assert all(a[1] <= b[0] for a, b in itertools.pairwise(spans)) and spans[-1][1] <= 800
    return [c["text"] for c in calls if c["color"] == "#b00020"]


@needs_node
def test_the_limit_is_in_the_legend_only_as_drawn() -> None:
    assert _legend(10.0, 12.0) == [".... ± limit"]
    assert _legend(200.0, 12.0) == ["± limit 200.0 µm: off scale"]
