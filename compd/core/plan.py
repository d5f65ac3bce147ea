"""What one cycle hands the shell, frozen: the `Plan` (what to write), the
`Outcome` the shell reports back (how the write went) and the `Row` that
closes the cycle: the cycle's one report, each name one meaning, read by every
output (pure data).

`Cycle.plan(...) -> Plan`, the shell writes `plan.writes`, then
`Cycle.commit(outcome) -> Row`. Nothing is changed after it is returned: a
write that failed is in the row that `commit` returns, not patched into an
earlier one. `Plan` and `Row` are named tuples (made once a cycle each, and a
tuple is built several times faster than a frozen dataclass of 20-odd
fields) whose mappings are read-only views; the rest are frozen dataclasses.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, NamedTuple

from compd.core.axes import AxisRow
from compd.core.events import Event
from compd.core.faults import FaultState
from compd.core.health import Cause
from compd.core.record import RecordRow

#: a cycle without per-axis outputs
NO_AXES: Mapping[str, AxisRow] = MappingProxyType({})

__all__ = ["NO_AXES", "WRITTEN", "AdaptationView", "Outcome", "Plan", "Row", "Snapshot"]


class Plan(NamedTuple):
    """One cycle's decision: what to write and why (the `Row` fields known before
    the write, by the same names)."""

    sequence: int
    #: the cycle's machine time (s) and wall-clock time (s, NaN when none was
    #: given): read once by the loop, passed to `plan`
    machine_s: float
    wall_s: float
    #: output name -> value in controller units (read-only)
    writes: Mapping[str, float]
    #: the output stage's value in µm (after clamp, slew limit and fault policy)
    stage_um: float
    #: the offset in this cycle's writes (µm), None: none written
    sent_um: float | None
    #: the model's output as recorded (None: not stepped, or not recorded)
    model_um: float | None
    shadow_um: float | None
    #: the state the cycle records (`compd.core.health_view.recorded_state`)
    state: FaultState
    status: int
    heartbeat: int
    #: every channel the live model reads valid and the model stepped (heartbeat advanced)
    inputs_valid: bool
    #: why the offset compd wants is not in force, as planned (`Row.cause` after the write)
    cause: Cause
    #: each channel's value (None: missing or not finite), why each is invalid
    #: (None: valid), each term's contribution (µm), the probe that arrived (read-only)
    channels: Mapping[str, float | None]
    validity: Mapping[str, str | None]
    contributions: Mapping[str, float]
    probe: Mapping[str, Any] | None = None
    events: tuple[Event, ...] = ()
    #: a ramp-to-zero shutdown has reached zero (or cannot write any more)
    shutdown_done: bool = False


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


class Row(NamedTuple):
    """The cycle's report: a committed cycle, one meaning per name, frozen
    (mappings read-only). Every output reads the field it means:

    - `stage_um` the output stage's value (``compd_offset_micrometres``, the
      status page's ``offset_um``, the shutdown ramp);
    - `sent_um` the offset written this cycle (None: none written), and
      `write_ok` whether this cycle's writes arrived (the recorder's
      ``attempted_um``; its ``offset_um`` is `sent_um` when they did);
    - `confirmed_um` the offset the controller last confirmed holding, after
      this cycle's write (None: unknown): ``compd_offset_confirmed_micrometres``,
      the OPC UA face's ``Offset_um``, the page's ``confirmed_um``, the checkpoint;
    - `inputs_valid` every channel the model reads valid and the model stepped
      (the heartbeat advanced; the recorder's ``valid``);
    - `in_force` a COMPLETE cycle (`compd.core.cycle.offset_in_force`): what the
      model asks for is the offset in force (``compd_cycles_complete``, the
      recorder's ``complete``, the checkpoint's last complete cycle, the page's
      ``complete``);
    - `machine_s`, `wall_s` the cycle's time, read once by the loop.
    """

    sequence: int
    machine_s: float
    wall_s: float
    writes: Mapping[str, float]
    stage_um: float
    sent_um: float | None
    write_ok: bool
    confirmed_um: float | None
    model_um: float | None
    shadow_um: float | None
    state: FaultState
    status: int
    heartbeat: int
    inputs_valid: bool
    in_force: bool
    #: why the offset compd wants is not in force after the write, or that it is
    #: (`compd.core.health.Cause`): what health, the page and the faces say
    cause: Cause
    channels: Mapping[str, float | None]
    validity: Mapping[str, str | None]
    contributions: Mapping[str, float]
    probe: Mapping[str, Any] | None
    #: what the faces show of the cycle beyond the offset and the cause
    snapshot: Snapshot
    #: the plan's events (logged before the write), then what the write's outcome
    #: caused (write_failed, write_fault, ..._stopped)
    events: tuple[Event, ...] = ()
    write_events: tuple[Event, ...] = ()
    shutdown_done: bool = False
    #: axis -> its part of the cycle (``[output.axes]``: the line's value and slope,
    #: the axis's state, cause and status word; `compd.core.axes.AxisRow`), read-only;
    #: empty without per-axis outputs
    axes: Mapping[str, AxisRow] = NO_AXES

    @property
    def healthy(self) -> bool:
        """The offset compd wants is in force, or an operator holds it (`Cause.healthy`)."""
        return self.cause.healthy

    @property
    def record(self) -> RecordRow:
        """This cycle as the recorder stores it (its columns' names: ``offset_um``
        the offset sent and confirmed, ``attempted_um`` the offset sent,
        ``complete`` in force, ``valid`` inputs valid, ``mono_s`` machine time)."""
        return RecordRow(
            seq=self.sequence, mono_s=self.machine_s, wall_s=self.wall_s,
            offset_um=self.sent_um if self.write_ok else None, model_um=self.model_um,
            state=self.state, valid=self.inputs_valid, channels=self.channels,
            validity=self.validity, contributions=self.contributions,
            attempted_um=self.sent_um, probe=self.probe, complete=self.in_force,
            axes=self.axes)
