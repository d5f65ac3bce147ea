"""The fault-state names live once, in `compd.core.faults.FaultState`."""

from __future__ import annotations

import json

from compd.core.faults import GAUGE_ALARM, FaultState


def test_every_state_has_a_gauge_and_the_alarm_is_no_offset_reaching_the_machine() -> None:
    gauges = {s: s.gauge for s in FaultState}
    # stopped (refused for good), held (a foreign offset beyond the limit),
    # write_fault (writes failing in a row)
    assert [s for s, g in gauges.items() if g >= GAUGE_ALARM] == [
        FaultState.STOPPED, FaultState.HELD, FaultState.WRITE_FAULT]
    assert gauges[FaultState.OK] == 0
    assert gauges[FaultState.INIT] == gauges[FaultState.HOLD] == 1  # not compensating
    assert gauges[FaultState.HOLD] < gauges[FaultState.RAMP] < GAUGE_ALARM


def test_states_are_their_names_in_rows_logs_and_json() -> None:
    held: str = FaultState.HOLD  # a str itself, equal to its name
    assert held == "hold" and str(FaultState.RAMP) == "ramp"
    assert f"state {FaultState.OK}" == "state ok"
    assert json.dumps({"state": FaultState.STOPPED}) == '{"state": "stopped"}'
