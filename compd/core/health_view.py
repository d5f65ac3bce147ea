"""One cycle's health as the PLC and the faces are told it (pure): a frozen
`HealthView` of `compd.core.health.OutputHealth` and the output stage, and
three functions of it alone, so none can disagree with another:
`recorded_state(view)` the state a cycle records (``stopped``, ``held`` and
``write_fault`` over the policy's), `status_word(view)` its status word (bits
in `compd.core.output.Status`; `status_bits(view)` the same as a plain int),
`output_cause(view)` why the offset compd wants is not in force
(`compd.core.health.Cause`, in its order).

A view is made once a cycle for the offset and once for each axis
(``[output.axes]``), so it is a named tuple: built several times faster than a
frozen dataclass of twenty fields, and as immutable.
"""

from __future__ import annotations

from typing import NamedTuple

from compd.core.faults import FaultState
from compd.core.health import Cause
from compd.core.output import Status

__all__ = ["HealthView", "output_cause", "recorded_state", "status_bits", "status_word"]

#: the policy's states that hold the output where it is
_HOLDING = (FaultState.HOLD, FaultState.INIT)


class HealthView(NamedTuple):
    """One cycle's health, frozen: all `status_word`, `recorded_state` and `output_cause` read."""

    #: the fault policy's state this cycle (init, ok, hold, ramp, shutdown)
    policy: FaultState
    #: the policy's alarm (ramping on a fault)
    alarm: bool = False
    write_stopped: bool = False
    write_fault: bool = False
    #: the controller holds an offset beyond ±limit: none written (`OutputStage.held`)
    held: bool = False
    #: a foreign read-back, alarmed until the output has ramped to its target
    foreign: bool = False
    operator_hold: bool = False
    slewing: bool = False
    #: this cycle's model: non-finite, far beyond the limit, worse than none (probes)
    model_invalid: bool = False
    model_range: bool = False
    model_worse: bool = False
    #: the controller takes no offset now (machine off, E-stop): held, none written
    controller_off: bool = False
    #: why this cycle is not valid (the fault policy's reason), None when it is
    invalid: Cause | None = None
    #: read-back is configured and failed this cycle: no offset written
    no_readback: bool = False
    #: the target the policy chose is beyond ±limit_um (the stage clamps it)
    at_limit: bool = False
    #: a tracking output held for [output] update_permitted: WAITING_FOR_PERMISSION or
    #: PERMIT_UNREADABLE; None: permitted (or no permit input)
    permit: Cause | None = None
    #: a fallback model stands in for an invalid input this cycle
    degraded: bool = False
    #: recorder only: nothing is written (RECORDER_ONLY once the inputs are valid)
    recorder_only: bool = False


def output_cause(v: HealthView) -> Cause:
    """Why the offset compd wants is not in force this cycle (`Cause`, in its order)."""
    if v.policy == FaultState.SHUTDOWN:
        return Cause.SHUTTING_DOWN
    if v.write_stopped:
        return Cause.WRITE_STOPPED
    if v.held:
        return Cause.FOREIGN_OFFSET_HELD
    if v.controller_off:
        return Cause.CONTROLLER_OFF
    if v.write_fault:
        return Cause.WRITE_FAULT
    if v.invalid is not None:
        return v.invalid
    if v.policy != FaultState.OK:  # not reached: the policy holds only on an invalid cycle
        return Cause.INPUTS_INVALID
    if v.recorder_only:
        return Cause.RECORDER_ONLY
    if v.no_readback:
        return Cause.NO_READBACK
    if v.foreign:
        return Cause.FOREIGN_OFFSET
    if v.permit is Cause.PERMIT_UNREADABLE:
        return v.permit
    if v.operator_hold:
        return Cause.OPERATOR_HOLD
    if v.permit is not None:
        return v.permit
    if v.at_limit:
        return Cause.AT_LIMIT
    return Cause.DEGRADED if v.degraded else Cause.IN_FORCE


def recorded_state(v: HealthView) -> FaultState:
    """The state recorded and reported: the policy's, unless the offset is not
    reaching the controller (stopped, held, a tracking output held while the
    controller is off, write fault, in that order)."""
    if v.write_stopped:
        return FaultState.STOPPED
    if v.held:
        return FaultState.HELD
    if v.controller_off and v.policy == FaultState.OK:
        return FaultState.HOLD
    return FaultState.WRITE_FAULT if v.write_fault else v.policy


def _state_bits(v: HealthView) -> int:
    """OK, HOLDING, RAMPING or SHUTDOWN: what the output does."""
    if v.policy == FaultState.OK and not (v.write_stopped or v.held or v.write_fault):
        held = v.operator_hold or v.controller_off or v.permit is not None
        return _HOLDING_BIT if held else _OK_BIT
    if v.policy in _HOLDING:
        return _HOLDING_BIT
    if v.policy == FaultState.RAMP:
        return _RAMPING
    if v.policy == FaultState.SHUTDOWN:
        return _SHUTDOWN
    return 0


# the bits as plain ints: `status_bits` runs once a cycle per output
_OK_BIT, _HOLDING_BIT, _ALARM = int(Status.OK), int(Status.HOLDING), int(Status.ALARM)
_RAMPING, _SHUTDOWN = int(Status.RAMPING), int(Status.SHUTDOWN)
_MODEL_INVALID = int(Status.MODEL_INVALID)
_MODEL_RANGE = int(Status.MODEL_RANGE) | _ALARM
_MODEL_WORSE = int(Status.MODEL_WORSE) | _ALARM
_MISMATCH = int(Status.READBACK_MISMATCH) | _ALARM
_WRITE_STOPPED = int(Status.WRITE_STOPPED) | _ALARM
_OFFSET_HELD = int(Status.OFFSET_HELD) | _ALARM
_WRITE_FAULT = int(Status.WRITE_FAULT) | _ALARM
_OPERATOR_HOLD = int(Status.OPERATOR_HOLD)
_SLEWING = int(Status.SLEWING)
_CONTROLLER_OFF = int(Status.CONTROLLER_OFF)


def status_bits(v: HealthView) -> int:
    """The status word a cycle writes as a plain int (bits in
    `compd.core.output.Status`): `status_word` without building the flag."""
    s = _state_bits(v)
    if v.model_invalid:
        s |= _MODEL_INVALID
    if v.model_range:
        s |= _MODEL_RANGE
    if v.model_worse:
        s |= _MODEL_WORSE
    if v.foreign:
        s |= _MISMATCH
    if v.alarm:
        s |= _ALARM
    if v.write_stopped:
        s |= _WRITE_STOPPED
    if v.held:
        s |= _OFFSET_HELD
    if v.write_fault:
        s |= _WRITE_FAULT
    if v.operator_hold:
        s |= _OPERATOR_HOLD
    if v.slewing:
        s |= _SLEWING
    if v.controller_off:
        s |= _CONTROLLER_OFF
    return s


def status_word(v: HealthView) -> Status:
    """The status word a cycle writes (bits in `compd.core.output.Status`)."""
    return Status(status_bits(v))
