"""Events carry their level: one declaration per name, each at the level the
daemon logs it at, and no undeclared name."""

from __future__ import annotations

import pytest

from compd.core.events import Event, EventName, Level

#: the daemon's _WARNINGS and _ERRORS before the names became an enum
WAS_WARNING = {"channel_invalid", "fault_hold", "readback_mismatch", "write_failed",
               "offset_write_skipped", "checkpoint_unusable", "checkpoint_state_refused",
               "model_non_finite", "probe_refused", "adaptation_state_refused",
               "adaptation_stood_down",
               # LinuxCNC: a machine off or in E-stop
               "controller_off",
               # the offset compd wrote beyond a limit lowered since: it ramps in
               "offset_beyond_limit",
               # a long run of probes the gate refused: the model or the probe is wrong
               "probes_disagree",
               # a re-zero moves the offset (an audit line); one refused or dropped; a
               # permit input that cannot be read (taken as not permitted)
               "rezero", "rezero_refused", "rezero_dropped", "permit_unreadable",
               # a sensor lost: the fallback model on the others is in force (degraded)
               "fallback_in_force"}
WAS_ERROR = {"fault_ramp_to_zero", "offset_write_stopped", "output_write_stopped",
             "readback_out_of_range", "write_fault", "model_out_of_range",
             "model_worse_than_none"}


def test_every_level_is_the_one_the_daemon_logged_it_at() -> None:
    for name in EventName:
        if name in ("operator_hold", "operator_release"):  # logged as warnings directly
            assert name.level is Level.WARNING
        elif name.value in WAS_ERROR:
            assert name.level is Level.ERROR, name
        elif name.value in WAS_WARNING:
            assert name.level is Level.WARNING, name
        else:
            assert name.level is Level.INFO, name
    assert {n.value for n in EventName} >= WAS_WARNING | WAS_ERROR


def test_an_event_is_made_from_its_name_and_equals_it_as_a_string() -> None:
    ev = Event(EventName.FAULT_HOLD, {"hold_s": 5.0})
    assert ev.name == "fault_hold" and ev.level is Level.WARNING
    assert Event("write_fault").name is EventName.WRITE_FAULT  # type: ignore[arg-type]


def test_an_undeclared_name_is_refused_where_the_event_is_made() -> None:
    with pytest.raises(ValueError, match="fault_hodl"):
        Event("fault_hodl")  # type: ignore[arg-type]
