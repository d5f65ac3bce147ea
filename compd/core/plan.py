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

from collections.abc import Mapping
from dataclasses import dataclass

from compd.core.faults import Event, FaultState
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
    shadow_um: float | None
    status: int
    heartbeat: int
    #: inputs valid and the model stepped (heartbeat advanced)
    complete: bool
    #: the row as planned, before the write (`offset_um`: sent, not yet
    #: confirmed; `complete` False): `commit` makes the final `Row.record`
    #: (wall_s: as passed to `plan`, NaN when none was)
    record: RecordRow
    events: tuple[Event, ...] = ()
    #: a ramp-to-zero shutdown has reached zero (or cannot write any more)
    shutdown_done: bool = False

    @property
    def model_um(self) -> float | None:
        return self.record.model_um

    @property
    def state(self) -> FaultState:
        return FaultState(self.record.state)


@dataclass(frozen=True, slots=True)
class Outcome:
    """How the shell's write of a plan went: `WRITTEN` (every write arrived,
    or there was nothing to write), or `Outcome.failed(...)`."""

    ok: bool = True
    #: the refused output(s) when known (comma-separated for a combined write)
    output: str | None = None
    #: the controller refused for good (no retry); transient otherwise
    permanent: bool = False
    reason: str = ""

    @classmethod
    def failed(cls, output: str | None, *, permanent: bool = False,
               reason: str = "") -> Outcome:
        return cls(False, output, permanent, reason)


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


@dataclass(frozen=True, slots=True)
class Snapshot:
    """What the faces show of the cycle beyond its row, taken at commit."""

    #: the last offset the controller confirmed (None: unknown)
    confirmed_um: float | None
    operator_hold: bool
    adaptation: AdaptationView | None = None


@dataclass(frozen=True, slots=True)
class Row:
    """A committed cycle: its plan's figures and events, the final `record`,
    and the events of its write's outcome (`write_events`, after `events`)."""

    sequence: int
    writes: Mapping[str, float]
    offset_um: float
    shadow_um: float | None
    status: int
    heartbeat: int
    #: inputs valid and the model stepped (heartbeat advanced)
    complete: bool
    #: the recorder's row: `offset_um` what the controller confirmed,
    #: `complete` a COMPLETE cycle (`compd.core.cycle.offset_in_force`)
    record: RecordRow
    snapshot: Snapshot
    events: tuple[Event, ...] = ()
    shutdown_done: bool = False
    #: what the write's outcome caused (write_failed, write_fault, ..._stopped)
    write_events: tuple[Event, ...] = ()

    @property
    def model_um(self) -> float | None:
        return self.record.model_um

    @property
    def state(self) -> FaultState:
        return FaultState(self.record.state)

    @property
    def in_force(self) -> bool:
        """A complete cycle (`compd.core.cycle.offset_in_force`)."""
        return self.record.complete
