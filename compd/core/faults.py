"""The fault policy: what the output aims at when inputs go bad (pure).

States:

- ``init``  no valid sample yet since start: the output holds where it is
- ``ok``    inputs valid: target = the model's δZ
- ``hold``  inputs invalid for less than hold_s: target = the current output
- ``ramp``  invalid for hold_s or longer: target = 0, reached at the slew
  limit, alarm bit set
- ``shutdown``  a ramp-to-zero shutdown: target = 0 whatever the inputs

Recovery (valid again) goes straight back to ``ok``; the output stage's slew
limit makes it a ramp, never a jump.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

State = Literal["init", "ok", "hold", "ramp", "shutdown"]


@dataclass(frozen=True, slots=True)
class Event:
    """Something the shell logs: an event name and its fields."""

    name: str
    fields: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class Decision:
    state: State
    #: None: hold the current output
    target_um: float | None
    alarm: bool


class FaultPolicy:
    """Decides the output's target from validity and time (machine seconds)."""

    def __init__(self, hold_s: float) -> None:
        self.hold_s = hold_s
        self.state: State = "init"
        self.invalid_since_s: float | None = None
        self.shutting_down = False

    def decide(self, now_s: float, valid: bool, model_um: float | None,
               events: list[Event]) -> Decision:
        if self.shutting_down:
            return self._to("shutdown", Decision("shutdown", 0.0, False), events, now_s)
        if valid and model_um is not None:
            if self.state in ("hold", "ramp"):
                events.append(Event("fault_recovered", {
                    "after_s": now_s - (self.invalid_since_s or now_s)}))
            self.invalid_since_s = None
            return self._to("ok", Decision("ok", model_um, False), events, now_s)
        if self.invalid_since_s is None:
            self.invalid_since_s = now_s
        if self.state == "init":
            return Decision("init", None, False)
        if now_s - self.invalid_since_s >= self.hold_s:
            return self._to("ramp", Decision("ramp", 0.0, True), events, now_s)
        return self._to("hold", Decision("hold", None, False), events, now_s)

    def _to(self, state: State, decision: Decision, events: list[Event],
            now_s: float) -> Decision:
        if state != self.state:
            if state == "hold":
                events.append(Event("fault_hold", {"hold_s": self.hold_s}))
            elif state == "ramp":
                events.append(Event("fault_ramp_to_zero", {
                    "invalid_for_s": now_s - (self.invalid_since_s or now_s)}))
            elif state == "shutdown":
                events.append(Event("shutdown_ramp_to_zero"))
            self.state = state
        return decision
