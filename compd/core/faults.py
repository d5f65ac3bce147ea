"""The fault policy: what the output aims at when inputs go bad (pure).

States:

- ``init``  no valid sample yet since start: the output holds where it is
  (status bit HOLDING); after hold_s without one, ``ramp`` as for any fault
- ``ok``    inputs valid: target = the model's δZ
- ``hold``  inputs invalid for less than hold_s: target = the current output
- ``ramp``  invalid for hold_s or longer: target = 0, reached at the slew
  limit, alarm bit set
- ``shutdown``  a ramp-to-zero shutdown: target = 0 whatever the inputs
- ``stopped``  not a policy decision: the cycle stopped writing the offset (a
  permanent refusal by the controller); recorded and exported as the alarm
- ``held``  not a policy decision: the controller holds an offset beyond
  ±limit_um that compd did not write; no offset is written until it is back
  within the limit (`compd.core.output`); exported as the alarm
- ``write_fault``  not a policy decision: offset writes keep failing
  (`compd.core.cycle.WRITE_FAULT_AFTER` in a row); exported as the alarm

`FaultState` holds these names once (a `StrEnum`: each member equals its
name as a string, in the recorder's rows and the logs); `FaultState.gauge` is
the number of the ``compd_fault_state`` metric.

Recovery (valid again) goes straight back to ``ok``; the output stage's slew
limit makes it a ramp, never a jump.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from compd.core.events import Event, EventName

__all__ = ["GAUGE_ALARM", "Decision", "Event", "FaultPolicy", "FaultState"]


class FaultState(enum.StrEnum):
    INIT = "init"
    OK = "ok"
    HOLD = "hold"
    RAMP = "ramp"
    SHUTDOWN = "shutdown"
    STOPPED = "stopped"
    HELD = "held"
    WRITE_FAULT = "write_fault"

    @property
    def gauge(self) -> int:
        """The ``compd_fault_state`` metric: 0 ok, 1 hold (and init: not compensating
        yet), 2 ramp, 3 alarm/stopped."""
        return _GAUGE[self]


#: ``compd_fault_state`` at or above this: the daemon no longer compensates
GAUGE_ALARM = 3
_GAUGE = {FaultState.INIT: 1, FaultState.OK: 0, FaultState.HOLD: 1, FaultState.RAMP: 2,
          FaultState.SHUTDOWN: 2, FaultState.STOPPED: GAUGE_ALARM,
          FaultState.HELD: GAUGE_ALARM, FaultState.WRITE_FAULT: GAUGE_ALARM}


@dataclass(frozen=True, slots=True)
class Decision:
    state: FaultState
    #: None: hold the current output
    target_um: float | None
    alarm: bool


class FaultPolicy:
    """Decides the output's target from validity and time (machine seconds)."""

    def __init__(self, hold_s: float) -> None:
        self.hold_s = hold_s
        self.state: FaultState = FaultState.INIT
        self.invalid_since_s: float | None = None
        self.shutting_down = False

    def decide(self, now_s: float, valid: bool, model_um: float | None,
               events: list[Event]) -> Decision:
        if self.shutting_down:
            return self._to(FaultState.SHUTDOWN, Decision(FaultState.SHUTDOWN, 0.0, False),
                            events, now_s)
        if valid and model_um is not None:
            if self.state in (FaultState.HOLD, FaultState.RAMP):
                events.append(Event(EventName.FAULT_RECOVERED, {
                    "after_s": now_s - (self.invalid_since_s or now_s)}))
            self.invalid_since_s = None
            return self._to(FaultState.OK, Decision(FaultState.OK, model_um, False),
                            events, now_s)
        if self.invalid_since_s is None:
            self.invalid_since_s = now_s
        if self.state == FaultState.INIT:
            # no valid sample since start: hold what the controller has, and like any
            # other fault ramp to zero with the alarm after hold_s (a sensor broken
            # across a restart once held a stale offset forever with status 0)
            if now_s - self.invalid_since_s >= self.hold_s:
                return self._to(FaultState.RAMP, Decision(FaultState.RAMP, 0.0, True),
                                events, now_s)
            return Decision(FaultState.INIT, None, False)
        if now_s - self.invalid_since_s >= self.hold_s:
            return self._to(FaultState.RAMP, Decision(FaultState.RAMP, 0.0, True), events, now_s)
        return self._to(FaultState.HOLD, Decision(FaultState.HOLD, None, False), events, now_s)

    def _to(self, state: FaultState, decision: Decision, events: list[Event],
            now_s: float) -> Decision:
        if state != self.state:
            if state == FaultState.HOLD:
                events.append(Event(EventName.FAULT_HOLD, {"hold_s": self.hold_s}))
            elif state == FaultState.RAMP:
                events.append(Event(EventName.FAULT_RAMP_TO_ZERO, {
                    "invalid_for_s": now_s - (self.invalid_since_s or now_s)}))
            elif state == FaultState.SHUTDOWN:
                events.append(Event(EventName.SHUTDOWN_RAMP_TO_ZERO))
            self.state = state
        return decision
