"""The output's states (pure data; the cycle's events are `compd.core.events`,
`Event` re-exported here). One state machine
(`compd.core.health.OutputHealth`) owns every state; the fault policy, its
part, decides what the output aims at when inputs go bad.

States:

- ``init``  no valid sample yet since start: the output holds where it is
  (status bit HOLDING); after hold_s without one, ``ramp`` as for any fault
- ``ok``    inputs valid: target = the model's δZ
- ``hold``  inputs invalid for less than hold_s: target = the current output
- ``ramp``  invalid for hold_s or longer: target = 0, reached at the slew
  limit, alarm bit set
- ``shutdown``  a ramp-to-zero shutdown: target = 0 whatever the inputs
- ``stopped``  not the policy's: the cycle stopped writing the offset (a
  permanent refusal by the controller); recorded and exported as the alarm
- ``held``  not the policy's: the controller holds an offset beyond
  ±limit_um that compd did not write; no offset is written until it is back
  within the limit (`compd.core.output`); exported as the alarm
- ``write_fault``  not the policy's: offset writes keep failing
  (`compd.core.health.WRITE_FAULT_AFTER` in a row); exported as the alarm

`FaultState` holds these names once (a `StrEnum`: each member equals its
name as a string, in the recorder's rows and the logs); `FaultState.gauge` is
the number of the ``compd_fault_state`` metric.

Recovery (valid again) goes straight back to ``ok``; the output stage's slew
limit makes it a ramp, never a jump.
"""

from __future__ import annotations

import enum

from compd.core.events import Event

__all__ = ["GAUGE_ALARM", "Event", "FaultState"]


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
