"""The output's health: one state machine that owns every `FaultState`, and
why the offset compd wants is not in force (`Cause`) (pure: no clock, no I/O).

`OutputHealth` holds everything that decides what the output aims at and
what the PLC is told:

- the fault policy's part (``init``, ``ok``, ``hold``, ``ramp``,
  ``shutdown``): validity against time (`decide`; see `compd.core.faults`
  for what each state means);
- what the writes told (`write_succeeded`, `write_failed`): a write fault
  after `WRITE_FAULT_AFTER` transient failures in a row, offset writes
  stopped after a permanent refusal, other outputs stopped one by one;
- what the read-back told (`foreign`: a value compd did not write, alarmed
  until the output has ramped back to its target);
- the model's range latch (`model_range`) and the operator's hold;
- what the controller says of itself (`controller`: machine off or E-stop,
  ``[output] machine_on``/``estop``): it takes no offset, so none is
  written and the output holds (CONTROLLER_OFF, HOLDING, state "hold"
  where the policy says "ok"); no alarm, it is the machine's own state.

What the PLC and every face are told of one cycle's health (the state
recorded, the status word, the `Cause`) are pure functions of a frozen
`compd.core.health_view.HealthView`.

`Cause` is the one answer to "is the offset compd wants in force, and if not,
why": health (`compd health`, the metrics it reads, the checkpoint's
``last_cause``), the status page and `compd status`, the OPC UA face and the
fault events' ``reason`` field are all derived from it. Every cause but
IN_FORCE, OPERATOR_HOLD, WAITING_FOR_PERMISSION (the controller holds the
offset by intent: a change only between cuts), RECORDER_ONLY (a run that only
records: valid inputs recorded, nothing written by intent) and DEGRADED is
unhealthy (`Cause.healthy`). DEGRADED (a fallback model stands in for a failed
sensor) counts as healthy because the offset the daemon wants is computed from
valid inputs and is in force: the machine is compensated, by a model validated
at fit time, and turning a sensor fault into a red health check would restart or
page for a daemon doing its job; it is a warning instead (`compd health` says
so, the metrics carry ``compd_degraded``), and the sensor wants replacing. The cycle's
commit may turn a planned cause into a write's (`committed_cause`).
"""

from __future__ import annotations

import enum
from typing import NamedTuple

from compd.core.events import Event, EventName
from compd.core.faults import FaultState

#: this many offset writes in a row failing (transient) are a write fault:
#: WRITE_FAULT and ALARM, state "write_fault", until a write succeeds
WRITE_FAULT_AFTER = 5


class Cause(enum.StrEnum):
    """Why the offset compd wants is not in force this cycle (IN_FORCE: it is).

    A member equals its name as a string (the metrics' ``cause`` label, the
    checkpoint's ``last_cause``, the events' ``reason``). When several hold,
    `output_cause` names the first of: shutting down, writes stopped, a foreign
    offset held, the controller off, a write fault, why the cycle is invalid
    (the model worse than none, the controller not answering, inputs invalid,
    the model non-finite or out of range), recorder only, no read-back, a foreign
    offset being ramped back from, a permit input that cannot be read, an operator's hold,
    waiting for the controller's permission, the limit, a fallback model in force."""

    IN_FORCE = "in_force"
    #: an operator's hold (OPC UA SetHold): the offset stays put, by intent
    OPERATOR_HOLD = "operator_hold"
    #: a ramp-to-zero shutdown
    SHUTTING_DOWN = "shutting_down"
    #: the controller refused the offset for good: no offset written
    WRITE_STOPPED = "write_stopped"
    #: the controller holds an offset beyond ±limit that compd did not write: none written
    FOREIGN_OFFSET_HELD = "foreign_offset_held"
    #: the controller takes no offset (machine off, E-stop): none written
    CONTROLLER_OFF = "controller_off"
    #: WRITE_FAULT_AFTER offset writes in a row failed
    WRITE_FAULT = "write_fault"
    #: this cycle's offset write failed (transient): the controller keeps the last one
    WRITE_FAILED = "write_failed"
    #: the probes showed the compensation worse than none (latched): held, then ramped
    MODEL_WORSE_THAN_NONE = "model_worse_than_none"
    #: the read failed: nothing read (and nothing written while that lasts)
    CONTROLLER_NOT_ANSWERING = "controller_not_answering"
    #: a channel the model reads is invalid: held, then ramped
    INPUTS_INVALID = "inputs_invalid"
    #: the model's output was not a number: held, then ramped
    MODEL_NON_FINITE = "model_non_finite"
    #: the model's output was far beyond ±limit: held, then ramped
    MODEL_OUT_OF_RANGE = "model_out_of_range"
    #: read-back is configured and failed: the controller's offset unknown, none written
    NO_READBACK = "no_readback"
    #: another writer changed the offset: ramping back from its value (alarm)
    FOREIGN_OFFSET = "foreign_offset"
    #: the target is beyond ±limit_um: the limit is written, not what the model asks
    AT_LIMIT = "at_limit"
    #: [output] update_permitted reads 0: the offset in force is held until it permits
    WAITING_FOR_PERMISSION = "waiting_for_permission"
    #: [output] update_permitted could not be read (bad quality, not a number): taken as
    #: not permitted, the offset in force held
    PERMIT_UNREADABLE = "permit_unreadable"
    #: one input is invalid and the fallback model on the others is in force: the
    #: machine is compensated, less well (healthy, with a warning: `compd health`)
    DEGRADED = "degraded"
    #: recorder only ([output] enabled = false or no [model]): read, validated and
    #: recorded; nothing written to the controller, by intent
    RECORDER_ONLY = "recorder_only"

    @property
    def healthy(self) -> bool:
        """The offset compd wants is in force, or is held on purpose (an operator's
        hold, the controller's permission not given)."""
        return self in _HEALTHY


#: the healthy causes (`Cause.healthy`), built once: it is asked several times a cycle
_HEALTHY = (Cause.IN_FORCE, Cause.OPERATOR_HOLD, Cause.WAITING_FOR_PERMISSION,
            Cause.RECORDER_ONLY, Cause.DEGRADED)


class Decision(NamedTuple):
    """The fault policy's decision of one cycle (made once a cycle for the offset
    and for each axis: a named tuple, cheap to build)."""

    state: FaultState
    #: None: hold the current output
    target_um: float | None
    alarm: bool


class OutputHealth:
    """See the module docstring. `decide` once per cycle, then one of
    `write_succeeded` / `write_failed` when the shell reports the writes.

    Its fields are read by anyone and changed only by its own methods, one per
    transition: the controller's state (`controller`), the fault policy
    (`decide`, `begin_shutdown`), the writes (`write_succeeded`,
    `write_failed`), a foreign read-back (`foreign_seen`, `foreign_settled`),
    the model's range (`model_in_range`), the operator (`set_operator_hold`),
    and a reload (`carry_over`)."""

    def __init__(self, hold_s: float, *, operator_hold: bool = False) -> None:
        self.hold_s = hold_s
        #: the fault policy's state (init, ok, hold, ramp, shutdown)
        self.policy: FaultState = FaultState.INIT
        self.invalid_since_s: float | None = None
        #: why the policy holds or ramps (None while it tracks the model)
        self.fault_cause: Cause | None = None
        self.shutting_down = False
        self.write_stopped = False
        self.stopped_outputs: set[str] = set()
        #: offset writes failed in a row; a write fault from WRITE_FAULT_AFTER on
        self.failed_writes = 0
        self.write_fault = False
        #: a foreign read-back was seen: alarm until the output tracks again
        self.foreign = False
        #: the model's output was beyond its range last cycle (events on change)
        self.model_range = False
        #: an operator's hold (`set_operator_hold`): the offset stays where it is
        self.operator_hold = operator_hold
        #: why the controller takes no offset now ("machine_off", "estop", "not_homed"),
        #: None: it does
        self.controller_off: str | None = None

    def carry_over(self, old: OutputHealth, *, outputs_same: bool) -> None:
        """A reload: keep the fault policy's timer and state (a hold goes on
        toward its ramp), and the stopped outputs when the outputs are the same."""
        self.policy, self.invalid_since_s = old.policy, old.invalid_since_s
        self.fault_cause = old.fault_cause
        self.shutting_down = old.shutting_down
        # a machine switched on during the reload still zeroed its offset
        self.controller_off = old.controller_off
        if outputs_same:
            self.write_stopped = old.write_stopped
            self.stopped_outputs = set(old.stopped_outputs)

    # -- the operator, the shutdown, the read-back and the model's range -----------------

    def set_operator_hold(self, on: bool) -> bool:
        """An operator's hold (on) or its release (off); whether that changed anything."""
        if on == self.operator_hold:
            return False
        self.operator_hold = on
        return True

    def begin_shutdown(self) -> None:
        """A ramp-to-zero shutdown: from the next `decide` on the target is 0."""
        self.shutting_down = True

    def foreign_seen(self) -> None:
        """The read-back showed a value compd did not write: alarmed from now on."""
        self.foreign = True

    def foreign_settled(self, *, moving: bool) -> None:
        """After the output stage moved: a foreign read-back's alarm lasts until the
        output has ramped to its target (`moving`: still slewing, or held)."""
        if self.foreign:
            self.foreign = moving

    def model_in_range(self, model_um: float, bound_um: float, events: list[Event]) -> bool:
        """Whether the model's output is within ±`bound_um`; MODEL_OUT_OF_RANGE and
        MODEL_IN_RANGE when that changes (a latch: told once each way)."""
        out = abs(model_um) > bound_um
        if out != self.model_range:
            self.model_range = out
            events.append(Event(EventName.MODEL_OUT_OF_RANGE if out else EventName.MODEL_IN_RANGE,
                                {"model_um": model_um, "bound_um": bound_um}))
        return not out

    # -- the controller's own state -----------------------------------------------------

    def controller(self, off: str | None, offset_um: float, events: list[Event]) -> str | None:
        """What the controller says this cycle: `off` why it takes no offset
        (None: it does). Returns why it was off when it is on again (the cycle
        then takes what it holds as the start), else None."""
        was, self.controller_off = self.controller_off, off
        if off is not None:
            if was != off:
                events.append(Event(EventName.CONTROLLER_OFF,
                                    {"reason": off, "offset_um": offset_um}))
            return None
        return was

    # -- the fault policy ---------------------------------------------------------------

    def decide(self, now_s: float, why: Cause | None, target_um: float | None,
               events: list[Event]) -> Decision:
        """The output's target from validity and time (machine seconds). `why`:
        why this cycle is not valid (`Cause`), None when it is (then `target_um`
        is the model's); the hold and ramp events carry it as ``reason``."""
        if self.shutting_down:
            return self._to(Decision(FaultState.SHUTDOWN, 0.0, False), events, now_s)
        if why is None and target_um is not None:
            if self.policy in (FaultState.HOLD, FaultState.RAMP):
                events.append(Event(EventName.FAULT_RECOVERED, {
                    "after_s": now_s - (self.invalid_since_s or now_s),
                    "was": str(self.fault_cause)}))
            self.invalid_since_s = None
            self.fault_cause = None
            return self._to(Decision(FaultState.OK, target_um, False), events, now_s)
        self.fault_cause = why if why is not None else Cause.INPUTS_INVALID
        if self.invalid_since_s is None:
            self.invalid_since_s = now_s
        if now_s - self.invalid_since_s >= self.hold_s:
            # init too: no valid sample since start holds what the controller has and,
            # like any other fault, ramps to zero with the alarm after hold_s (a sensor
            # broken across a restart once held a stale offset forever with status 0)
            return self._to(Decision(FaultState.RAMP, 0.0, True), events, now_s)
        if self.policy == FaultState.INIT:
            return Decision(FaultState.INIT, None, False)
        return self._to(Decision(FaultState.HOLD, None, False), events, now_s)

    def _to(self, decision: Decision, events: list[Event], now_s: float) -> Decision:
        state = decision.state
        if state != self.policy:
            reason = str(self.fault_cause)
            if state == FaultState.HOLD:
                events.append(Event(EventName.FAULT_HOLD, {
                    "reason": reason, "hold_s": self.hold_s}))
            elif state == FaultState.RAMP:
                events.append(Event(EventName.FAULT_RAMP_TO_ZERO, {
                    "reason": reason,
                    "fault_for_s": now_s - (self.invalid_since_s or now_s)}))
            elif state == FaultState.SHUTDOWN:
                events.append(Event(EventName.SHUTDOWN_RAMP_TO_ZERO))
            self.policy = state
        return decision

    def committed_cause(self, planned: Cause, *, offset_failed: bool) -> Cause:
        """The cause of a cycle whose writes the shell reported (after
        `write_succeeded` / `write_failed`): stopped writes or a write fault that
        began with this write name themselves, a failed offset write of a cycle
        that was in force is WRITE_FAILED; any other planned cause stands."""
        if not offset_failed:
            return planned
        if self.write_stopped:
            return Cause.WRITE_STOPPED
        if self.write_fault:
            return Cause.WRITE_FAULT
        return Cause.WRITE_FAILED if planned.healthy else planned

    # -- the writes' outcome ------------------------------------------------------------

    def write_succeeded(self, later: list[Event]) -> None:
        """The offset write arrived: a write fault ends (`later`: the next cycle's events)."""
        if self.write_fault:
            later.append(Event(EventName.WRITE_RECOVERED, {"failed_writes": self.failed_writes}))
        self.write_fault = False
        self.failed_writes = 0

    def write_failed(self, outputs: tuple[str, ...], *, permanent: bool, reason: str,
                     offset_failed: bool, offset_name: str, offset_um: float) -> list[Event]:
        """A write failed (`offset_failed`: it carried the offset; `outputs`:
        every output of the refused write, () when unknown); the events to log."""
        output = ",".join(outputs) or None  # the log line's field, as before
        if not permanent:
            return self._transient(output, reason, offset_failed, offset_um)
        names = set(outputs)
        if not names or offset_name in names:
            if self.write_stopped:
                return []
            self.write_stopped = True
            return [Event(EventName.OFFSET_WRITE_STOPPED, {
                "output": output, "reason": reason, "offset_um": offset_um})]
        events = [Event(EventName.OUTPUT_WRITE_STOPPED, {"output": name, "reason": reason})
                  for name in sorted(names - self.stopped_outputs)]
        self.stopped_outputs |= names
        return events

    def _transient(self, output: str | None, reason: str, offset_failed: bool,
                   offset_um: float) -> list[Event]:
        events = [Event(EventName.WRITE_FAILED, {"output": output, "reason": reason})]
        if offset_failed:
            self.failed_writes += 1
            if self.failed_writes >= WRITE_FAULT_AFTER and not self.write_fault:
                self.write_fault = True
                events.append(Event(EventName.WRITE_FAULT, {
                    "failed_writes": self.failed_writes, "reason": reason,
                    "offset_um": offset_um}))
        return events
