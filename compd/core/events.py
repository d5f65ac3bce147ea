"""What the cycle tells the shell: one `EventName` per kind of event, each
carrying the level it is logged at (pure data).

The names were bare strings, and their levels a pair of sets in the daemon
(``_WARNINGS``/``_ERRORS``): a name misspelt where an event is made, or one
added without a level, was logged as ``info`` and never reached the status
page's alarms. Here each name is declared once with its level; `Event`
refuses a name that is not declared (`EventName(...)` raises ValueError).

Levels: ``info`` a change for the better or a fact (recovered, restored,
initialised); ``warning`` compensation goes on degraded or holds (an invalid
channel, a hold, a refused probe); ``error`` the output ramps or stops
(ramp to zero, writes stopped, a model out of range or worse than none).
Warnings and errors also go to the status page's alarm list.

`EventName` is a `StrEnum`: a member equals its name as a string, in the
logs and wherever a test compares it with one. It lives in the core because
the core makes most events (the cycle, the output's health, adaptation); the
shell's start-up (`compd.runtime.startup`) makes the checkpoint's.
"""

from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

__all__ = ["Event", "EventName", "Level"]


class Level(enum.StrEnum):
    """A log level, as structlog's method names."""

    INFO = "info"
    WARNING = "warning"
    ERROR = "error"


_I, _W, _E = Level.INFO, Level.WARNING, Level.ERROR


class EventName(enum.StrEnum):
    """Every event the cycle and its start-up report, with its level."""

    level: Level

    def __new__(cls, value: str, level: Level = Level.INFO) -> EventName:
        member = str.__new__(cls, value)
        member._value_ = value
        member.level = level
        return member

    # the fault policy (compd.core.health)
    FAULT_HOLD = "fault_hold", _W
    FAULT_RAMP_TO_ZERO = "fault_ramp_to_zero", _E
    FAULT_RECOVERED = "fault_recovered", _I
    SHUTDOWN_RAMP_TO_ZERO = "shutdown_ramp_to_zero", _I
    # inputs and the model (compd.core.cycle, compd.core.modelstep)
    CHANNEL_INVALID = "channel_invalid", _W
    CHANNEL_VALID = "channel_valid", _I
    MODEL_INITIALISED = "model_initialised", _I
    MODEL_NON_FINITE = "model_non_finite", _W
    MODEL_OUT_OF_RANGE = "model_out_of_range", _E
    MODEL_IN_RANGE = "model_in_range", _I
    # the controller's offset read back
    READBACK_MISMATCH = "readback_mismatch", _W
    READBACK_OUT_OF_RANGE = "readback_out_of_range", _E
    READBACK_IN_RANGE = "readback_in_range", _I
    READBACK_ADOPTED = "readback_adopted", _I
    # the offset compd wrote is beyond a limit lowered since (a reload, a restart)
    OFFSET_BEYOND_LIMIT = "offset_beyond_limit", _W
    OFFSET_WITHIN_LIMIT = "offset_within_limit", _I
    # writes
    OFFSET_WRITE_SKIPPED = "offset_write_skipped", _W
    WRITE_FAILED = "write_failed", _W
    WRITE_FAULT = "write_fault", _E
    WRITE_RECOVERED = "write_recovered", _I
    OFFSET_WRITE_STOPPED = "offset_write_stopped", _E
    OUTPUT_WRITE_STOPPED = "output_write_stopped", _E
    # the operator (OPC UA SetHold)
    OPERATOR_HOLD = "operator_hold", _W
    OPERATOR_RELEASE = "operator_release", _W
    # the controller's permission to change the offset ([output] update_permitted)
    PERMISSION_WAITING = "permission_waiting", _I
    PERMISSION_GRANTED = "permission_granted", _I
    PERMIT_UNREADABLE = "permit_unreadable", _W
    # re-zero: the present prediction taken as the new zero (compd.core.modelstep)
    REZERO = "rezero", _W
    REZERO_REFUSED = "rezero_refused", _W
    REZERO_DROPPED = "rezero_dropped", _W
    #: one input invalid: the fallback model without it is in force (degraded)
    FALLBACK_IN_FORCE = "fallback_in_force", _W
    #: the lost input is valid again: the main model is in force
    FALLBACK_ENDED = "fallback_ended", _I
    # the controller takes no offset (machine off, E-stop: compd.core.health), and again
    CONTROLLER_OFF = "controller_off", _W
    CONTROLLER_ON = "controller_on", _I
    # adaptation (compd.core.adaptation)
    PROBE_ACCEPTED = "probe_accepted", _I
    PROBE_REFUSED = "probe_refused", _W
    ADAPTATION_REACQUIRED = "adaptation_reacquired", _I
    ADAPTATION_STOOD_DOWN = "adaptation_stood_down", _W
    ADAPTATION_RESUMED = "adaptation_resumed", _I
    ADAPTATION_STATE_REFUSED = "adaptation_state_refused", _W
    MODEL_WORSE_THAN_NONE = "model_worse_than_none", _E
    PROBES_DISAGREE = "probes_disagree", _W
    # start-up from the checkpoint (compd.runtime.startup)
    CHECKPOINT_RESTORED = "checkpoint_restored", _I
    CHECKPOINT_TOO_OLD = "checkpoint_too_old", _I
    CHECKPOINT_OTHER_MODEL = "checkpoint_other_model", _I
    CHECKPOINT_UNUSABLE = "checkpoint_unusable", _W
    CHECKPOINT_STATE_REFUSED = "checkpoint_state_refused", _W


def _frozen(value: Any) -> Any:
    if isinstance(value, Mapping):
        return MappingProxyType({k: _frozen(v) for k, v in value.items()})
    if isinstance(value, list | tuple):
        return tuple(_frozen(v) for v in value)
    return value


def _thawed(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {k: _thawed(v) for k, v in value.items()}
    if isinstance(value, tuple):
        return tuple(_thawed(v) for v in value)
    return value


@dataclass(frozen=True, slots=True)
class Event:
    """Something the shell logs: an event name (its level with it) and its fields,
    deep-frozen (a copy, its mappings read-only views, its lists tuples: the report
    reaches every sink, none may change what the next one reads); `plain` is
    the fields with plain dicts, for a log line."""

    name: EventName
    fields: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not isinstance(self.name, EventName):  # a bare string: checked, never logged as info
            object.__setattr__(self, "name", EventName(self.name))
        object.__setattr__(self, "fields", _frozen(self.fields))

    def plain(self) -> dict[str, Any]:
        thawed: dict[str, Any] = _thawed(self.fields)
        return thawed

    @property
    def level(self) -> Level:
        return self.name.level
