"""What one cycle hands the shell, frozen: the `Plan` (what to write), the
`Outcome` the shell reports back (how the write went) and the `Row` that
closes the cycle (the final record, with whether the controller confirmed
the offset), with the `Snapshot` every face reads (pure data).

`Cycle.plan(...) -> Plan`, the shell writes `plan.writes`, then
`Cycle.commit(outcome) -> Row`. Nothing is changed after it is returned: a
write that failed is in the row that `commit` returns, not patched into an
earlier one.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from compd.core.events import Event
from compd.core.faults import FaultState
from compd.core.health import Cause
from compd.core.record import RecordRow

__all__ = ["WRITTEN", "AdaptationView", "Outcome", "Plan", "Row", "Snapshot"]


@dataclass(frozen=True, slots=True)
class Plan:
    """One cycle's decision: what to write and why."""

    sequence: int
    #: output name -> value in controller units
    writes: Mapping[str, float]
    #: the output stage's value in µm (what is, or would be, written)
    offset_um: float
    model_um: float | None
    shadow_um: float | None
    #: the state the cycle records (`compd.core.health.recorded_state`)
    state: FaultState
    status: int
    heartbeat: int
    #: inputs valid and the model stepped (heartbeat advanced)
    complete: bool
    #: the `RecordRow`'s fields as planned (read them as `record`); never changed
    row_fields: Mapping[str, Any]
    #: why the offset compd wants is not in force, as planned (`Row.cause` after the write)
    cause: Cause
    events: tuple[Event, ...] = ()
    #: a ramp-to-zero shutdown has reached zero (or cannot write any more)
    shutdown_done: bool = False

    @property
    def record(self) -> RecordRow:
        """The row as planned, before the write (`offset_um`: sent, not yet
        confirmed; `complete` False; wall_s: as passed to `plan`, NaN when none
        was): `commit` makes the final `Row.record`. Built when asked for: the
        daemon reads only the committed row."""
        return RecordRow(**self.row_fields)


@dataclass(frozen=True, slots=True)
class Outcome:
    """How the shell's write of a plan went: `WRITTEN` (every write arrived,
    or there was nothing to write), or `Outcome.failed(...)`."""

    ok: bool = True
    #: the refused output(s) when known: every output of a refused combined
    #: write (a driver error's `channels`), () when the error named none
    outputs: tuple[str, ...] = ()
    #: the controller refused for good (no retry); transient otherwise
    permanent: bool = False
    reason: str = ""

    @classmethod
    def failed(cls, outputs: Sequence[str] | str | None, *, permanent: bool = False,
               reason: str = "") -> Outcome:
        """`outputs`: the refused outputs' names (one name alone may be a
        string, never split), or None when unknown."""
        names = (outputs,) if isinstance(outputs, str) else tuple(outputs or ())
        return cls(False, tuple(n for n in names if n), permanent, reason)


#: every write of the plan reached the controller (or there was none)
WRITTEN = Outcome()


@dataclass(frozen=True, slots=True)
class AdaptationView:
    """The probe estimator's state after the cycle (`compd.core.adaptation`)."""

    bias_um: float
    bias_sigma_um: float
    correction_um: float
    standing_down: bool
    model_worse: bool
    #: the guard's evidence: accepted probes judged in its window, and of them how
    #: many showed the compensation worse than none (refused probes are not evidence)
    guard_probes: int = 0
    guard_worse: int = 0
    #: probes seen since start: accepted by the estimator, and refused (gate, fault, ...)
    probes_accepted: int = 0
    probes_refused: int = 0
    #: gate refusals in a row (`compd.core.adaptation.DISAGREE_AFTER`: the model
    #: or the probe source is wrong)
    gate_refusals: int = 0


@dataclass(frozen=True, slots=True)
class Snapshot:
    """What the faces show of the cycle beyond its row, taken at commit."""

    #: the last offset the controller confirmed (None: unknown)
    confirmed_um: float | None
    operator_hold: bool
    adaptation: AdaptationView | None = None
    #: waiting for the controller's permission: the change held back (µm), else None
    pending_um: float | None = None
    #: the re-zero in force (the raw prediction taken as zero, µm), None: never re-zeroed
    zero_um: float | None = None
    #: how the model started (restored, advanced, steady_state, first_start) and where
    #: its reference state came from (calibration, checkpoint, first_sample)
    model_start: str = ""
    reference: str = ""
    #: the input whose fallback model is in force (degraded), None: the main model
    fallback_for: str | None = None
    #: the reference state in force (°C per relative input channel), None: not yet known
    references: Mapping[str, float] | None = None


@dataclass(frozen=True, slots=True)
class Row:
    """A committed cycle: its plan, the final `record`, what the faces show
    (`snapshot`) and the events of its write's outcome (`write_events`, after
    the plan's `events`). The plan's figures read through."""

    plan: Plan
    #: the recorder's row: `offset_um` what the controller confirmed,
    #: `complete` a COMPLETE cycle (`compd.core.cycle.offset_in_force`)
    record: RecordRow
    snapshot: Snapshot
    #: what the write's outcome caused (write_failed, write_fault, ..._stopped)
    write_events: tuple[Event, ...]
    #: why the offset compd wants is not in force after the write, or that it is
    #: (`compd.core.health.Cause`): what health, the page and the faces say
    cause: Cause

    @property
    def in_force(self) -> bool:
        """A complete cycle (`compd.core.cycle.offset_in_force`)."""
        return self.record.complete

    @property
    def healthy(self) -> bool:
        """The offset compd wants is in force, or an operator holds it (`Cause.healthy`)."""
        return self.cause.healthy

    @property
    def sequence(self) -> int:
        return self.plan.sequence

    @property
    def writes(self) -> Mapping[str, float]:
        return self.plan.writes

    @property
    def offset_um(self) -> float:
        """The output stage's value (what was written, or would have been)."""
        return self.plan.offset_um

    @property
    def model_um(self) -> float | None:
        return self.plan.model_um

    @property
    def shadow_um(self) -> float | None:
        return self.plan.shadow_um

    @property
    def state(self) -> FaultState:
        return self.plan.state

    @property
    def status(self) -> int:
        return self.plan.status

    @property
    def heartbeat(self) -> int:
        return self.plan.heartbeat

    @property
    def complete(self) -> bool:
        """Inputs valid and the model stepped (heartbeat advanced)."""
        return self.plan.complete

    @property
    def events(self) -> tuple[Event, ...]:
        return self.plan.events

    @property
    def shutdown_done(self) -> bool:
        return self.plan.shutdown_done
