"""The controller's say over the offset, as read each cycle (pure): its
permission to change it, and the re-zero input's edge.

While the controller withholds its permission (``permitted`` False:
``[output] update_permitted`` reads 0; None: it could not be read, taken as
not permitted, PERMIT_UNREADABLE) a cycle that would track the model holds
the offset in force (HOLDING, cause WAITING_FOR_PERMISSION with the pending
difference in `Snapshot.pending_um`); the model keeps stepping, and the next
permitted cycle moves the offset toward the model at the slew limit. Faults,
the operator's ramp and the shutdown ramp are not held: a ramp to zero is a
safety action (`Permit.cause`; PERMISSION_WAITING, PERMISSION_GRANTED and
PERMIT_UNREADABLE when it changes).

The rising edge of ``rezero_bit`` (``[output] rezero``, a PLC bit or an
M-code pulse: a known 0, then 1) re-zeroes (`Cycle.rezero`,
`compd.core.modelstep`) after this cycle's step: the target changes, the
output stage ramps to it at the slew limit; an unreadable value is no edge,
and the next readable one starts afresh (`RezeroEdge.rising`).
"""

from __future__ import annotations

from compd.core.events import Event, EventName
from compd.core.faults import FaultState
from compd.core.health import Cause, Decision
from compd.core.output import OutputStage

__all__ = ["Permit", "RezeroEdge"]


class Permit:
    """The permit as last told: "permitted", "waiting" or "unreadable"."""

    def __init__(self) -> None:
        self.told = "permitted"

    def cause(self, permitted: bool | None, decision: Decision, output: OutputStage,
              events: list[Event]) -> Cause | None:
        """Why a tracking output is held for the controller's permission (None: it
        is not); the events when the permit changes."""
        if decision.state != FaultState.OK:
            return None  # a fault holds or ramps whatever the permit: nothing to tell
        now = "permitted" if permitted else ("waiting" if permitted is False else "unreadable")
        if now != self.told:
            if now == "unreadable":
                events.append(Event(EventName.PERMIT_UNREADABLE, {
                    "action": "taken as not permitted: the offset in force is held"}))
            elif now == "waiting":
                events.append(Event(EventName.PERMISSION_WAITING, {
                    "offset_um": output.current_um}))
            else:
                target = decision.target_um
                events.append(Event(EventName.PERMISSION_GRANTED, {
                    "offset_um": output.current_um,
                    "pending_um": None if target is None else target - output.current_um,
                    "slew_um_s": output.slew_um_s}))
            self.told = now
        if now == "permitted":
            return None
        return Cause.WAITING_FOR_PERMISSION if now == "waiting" else Cause.PERMIT_UNREADABLE


class RezeroEdge:
    """The re-zero input's last readable value (an edge needs a known 0 before it)."""

    def __init__(self) -> None:
        self.last: bool | None = None

    def rising(self, bit: bool | None) -> bool:
        """This cycle's value as read (None: unreadable); whether it is a rising edge."""
        was, self.last = self.last, bit
        return bool(bit) and was is False
