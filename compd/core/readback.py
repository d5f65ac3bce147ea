"""Step 1 of a cycle: the controller's offset as read back, judged (pure).

The controller's offset (controller units) is judged against the value it
last confirmed (`OutputStage.observe`):

- a value compd did not write (a second writer, a restarted controller that
  forgot it) is an alarm (READBACK_MISMATCH and ALARM until the output has
  ramped back to its target at the slew limit: `OutputHealth.foreign_seen`,
  `OutputHealth.foreign_settled`);
- beyond ±limit_um it is an alarm and no offset is written (OFFSET_HELD,
  state "held") until the controller's value is back within the limit, and
  then the output ramps from there (READBACK_IN_RANGE);
- the value compd itself last wrote is no foreign value: beyond a limit
  lowered since (a reload, a restart) it ramps into the limit at the slew
  limit (SLEWING; OFFSET_BEYOND_LIMIT until it is within, then
  OFFSET_WITHIN_LIMIT: `ReadBack.note_limit`).

While the controller says it takes no offset (machine off, E-stop) the
read-back is not judged. The first read-back once it is on again is what the
controller holds (LinuxCNC zeroes its external offset at machine on): taken as
it is, no alarm, and the output ramps from it at the slew limit
(`ReadBack.controller_on`). With read-back configured, a cycle whose read-back
failed writes no offset: the controller's state is unknown
(OFFSET_WRITE_SKIPPED once, `ReadBack.skip_write`).
"""

from __future__ import annotations

import math

from compd.core.events import Event, EventName
from compd.core.health import OutputHealth
from compd.core.modelstep import finite_or_none
from compd.core.output import OutputStage, Readback

__all__ = ["ReadBack"]


class ReadBack:
    """What the read-back tells the output stage and the health (module docstring)."""

    def __init__(self, output: OutputStage, health: OutputHealth, tolerance_um: float) -> None:
        self.output = output
        self.health = health
        self.tolerance_um = tolerance_um
        #: the output is beyond ±limit_um (told once each way, `note_limit`)
        self._beyond_noted = False
        #: OFFSET_WRITE_SKIPPED told since the last offset written
        self._skip_noted = False

    def judge(self, value: float | None, *, off: str | None, was_off: str | None,
              events: list[Event]) -> None:
        """This cycle's read-back `value` (controller units, None: none read);
        `off`: why the controller takes no offset now, `was_off`: why it took
        none until now (`OutputHealth.controller`)."""
        if off is not None:
            return  # what it holds is not judged while it takes none
        if was_off is not None:
            self.controller_on(was_off, value, events)
        elif value is not None:
            self.observe(value, events)

    def observe(self, value: float, events: list[Event]) -> None:
        out = self.output
        rb_um = out.from_controller(value) if math.isfinite(value) else math.nan
        was_held, expected = out.held, out.confirmed_um
        if rb_um == expected and not was_held:
            # exactly what the controller last confirmed (every cycle, as a rule): a
            # match with nothing to align, tell or release (`OutputStage.observe`)
            return
        seen = out.observe(rb_um, self.tolerance_um)
        if seen is Readback.OUT_OF_RANGE:
            if not was_held:
                events.append(Event(EventName.READBACK_OUT_OF_RANGE, {
                    "expected_um": expected, "readback_um": finite_or_none(rb_um),
                    "limit_um": out.limit_um, "action": "offset writes held"}))
            self.health.foreign_seen()
            return
        if was_held:
            events.append(Event(EventName.READBACK_IN_RANGE, {
                "readback_um": rb_um, "action": "ramping from it"}))
            self.health.foreign_seen()
        if seen is Readback.ADOPTED:
            events.append(Event(EventName.READBACK_ADOPTED, {"offset_um": out.current_um}))
        elif seen is Readback.FOREIGN:
            events.append(Event(EventName.READBACK_MISMATCH, {
                "expected_um": expected, "readback_um": rb_um, "action": "ramping from it"}))
            self.health.foreign_seen()

    def controller_on(self, was: str, value: float | None, events: list[Event]) -> None:
        """The controller takes offsets again: what it holds now is the start, no
        alarm, ramped from at the slew limit; a value beyond ±limit, or one after a
        held offset, is judged as any read-back."""
        out = self.output
        rb_um = out.from_controller(value) if value is not None and math.isfinite(value) \
            else None
        if rb_um is not None and abs(rb_um) <= out.limit_um and not out.held:
            out.adopt(rb_um)
        elif value is not None:
            self.observe(value, events)
        events.append(Event(EventName.CONTROLLER_ON, {"was": was, "readback_um": rb_um}))

    def note_limit(self, events: list[Event]) -> None:
        """The offset compd wrote is beyond ±limit_um (`OutputStage.beyond_limit`):
        it ramps into it at the slew limit; told when it is found, and when it is
        within."""
        out = self.output
        beyond = out.beyond_limit
        if beyond == self._beyond_noted:
            return
        self._beyond_noted = beyond
        if beyond:
            events.append(Event(EventName.OFFSET_BEYOND_LIMIT, {
                "offset_um": out.current_um, "limit_um": out.limit_um,
                "slew_um_s": out.slew_um_s, "action": "ramping into the limit"}))
        else:
            events.append(Event(EventName.OFFSET_WITHIN_LIMIT, {
                "offset_um": out.current_um, "limit_um": out.limit_um}))

    def skip_write(self, events: list[Event]) -> float:
        """Read-back is configured and failed: no offset is written, the stage goes
        back to what the controller last confirmed; the offset left in force (µm)."""
        self.output.revert()
        if not self._skip_noted:
            events.append(Event(EventName.OFFSET_WRITE_SKIPPED, {"reason": "no_readback"}))
            self._skip_noted = True
        return self.output.current_um

    def written(self) -> None:
        """This cycle writes the offset: a later skip is told again."""
        self._skip_noted = False
