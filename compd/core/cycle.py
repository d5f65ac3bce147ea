"""The sample cycle, sans I/O: samples and the time in; writes, events and the
record row out. No asyncio, no logging, no clock of its own, so hours of
machine time are tested in milliseconds with a fake clock.

Two calls per cycle (the shape of h11: the core decides, the shell does the
I/O): `Cycle.plan(now_s, samples, readback_offset_um) -> Plan` decides what
to write; the shell writes `plan.writes` and reports how that went with
`Cycle.commit(outcome) -> Row`, the cycle's final record (frozen; whether the
controller confirmed the offset is in it). `plan`:

1. read-back: the controller's offset (controller units) against the value it
   last confirmed (`OutputStage.observe`); a value compd did not write (a
   second writer, a restarted controller that forgot it) is an alarm
   (READBACK_MISMATCH and ALARM until the output has ramped back to its
   target at the slew limit); beyond ±limit_um it is an alarm and no offset
   is written (OFFSET_HELD, state "held") until the controller's value is back
   within the limit, and then the output ramps from there. The value compd
   itself last wrote is no foreign value: beyond a limit lowered since (a
   reload, a restart) it ramps into the limit at the slew limit (SLEWING;
   OFFSET_BEYOND_LIMIT until it is within, then OFFSET_WITHIN_LIMIT);
2. validate every channel (`compd.core.validation`); the cycle is valid when every
   channel the live model reads is valid;
3. valid: initialise the model on the first valid sample if needed (restored
   state, or the steady state matching today's temperatures), then step it
   (and the shadow model) once; invalid: the filters are NOT stepped; a model
   output beyond MODEL_RANGE_FACTOR·limit_um makes the cycle invalid (a
   fault: hold, then ramp) with MODEL_RANGE and ALARM. The fallback models
   (`compd.core.fallback`) step beside it on every answered cycle; when exactly
   one channel the model reads is invalid and a fallback covers it, that
   fallback's output is the model's from the first invalid sample on (cause
   DEGRADED, no hold, no alarm; FALLBACK_IN_FORCE), the output stage ramps the
   difference at the slew limit, and the main model takes over again, ramped
   the same way, when the channel is valid (FALLBACK_ENDED);
4. the output's health (`compd.core.health`: the fault policy and every
   other state) picks the target; the output stage (`compd.core.output`)
   makes it safe; the status word is a pure function of the health.
   While the controller says it takes no offset (``controller_off``: machine
   off, E-stop; `[output] machine_on`/`estop`) the read-back is not judged,
   the output stage stands still and no offset is written (status
   CONTROLLER_OFF and HOLDING, state "hold"); the model keeps stepping. The
   first read-back once it is on again is what the controller holds (LinuxCNC
   zeroes its external offset at machine on): taken as it is, no alarm, and
   the output ramps from it at the slew limit;
   While the controller withholds its permission (``permitted`` False:
   ``[output] update_permitted`` reads 0; None: it could not be read, taken
   as not permitted, PERMIT_UNREADABLE) a cycle that would track the model
   holds the offset in force (HOLDING, cause WAITING_FOR_PERMISSION with the
   pending difference in `Snapshot.pending_um`); the model keeps stepping,
   and the next permitted cycle moves the offset toward the model at the slew
   limit. Faults, the operator's ramp and the shutdown ramp are not held: a
   ramp to zero is a safety action. The rising edge of ``rezero_bit``
   (``[output] rezero``, a PLC bit or an M-code pulse) re-zeroes
   (`Cycle.rezero`, `compd.core.modelstep`) after this cycle's step: the
   target changes, the output stage ramps to it at the slew limit;
5. writes: nothing at all in a recorder-only run (``params.recorder_only``:
   ``[output] enabled = false`` or no ``[model]``: no offset, heartbeat or
   status; cause RECORDER_ONLY while the inputs are valid, and a cycle whose
   inputs were valid and recorded is its complete one); else the offset
   (in controller units; omitted once the controller
   refused it permanently, and while read-back is configured but the read
   failed, since then the controller's state is unknown), the heartbeat
   (advanced only on a complete valid cycle) and the status word.

Each cycle names why the offset compd wants is not in force, or that it is
(`compd.core.health.Cause`, `Plan.cause` and after the write `Row.cause`):
health, the status page, the metrics, the OPC UA face and the fault events'
``reason`` all read it. A cycle is COMPLETE (`offset_in_force`: the one
definition, used by the daemon's metrics, the checkpoint that `compd health
--state-dir` reads, and the recorder's ``complete`` column) only when its
cause is healthy (in force, or an operator's hold: inputs valid and the
model stepped, state "ok", no foreign offset, write fault, stopped writes,
fault hold, ramp, shutdown or limit) and the controller confirmed this
cycle's offset write (`commit(WRITTEN)`). `Row.complete` is the narrower
"inputs valid, model stepped" that advances the heartbeat; `Row.in_force` is
the complete cycle.

WRITE_FAULT_AFTER offset writes failing in a row are a write fault (WRITE_FAULT
and ALARM, state "write_fault") until one succeeds. The row keeps what was
sent (`attempted_um`) apart from what the controller confirmed (`offset_um`:
None when the outcome said the offset did not arrive). A plan that is never
committed (a test stepping without writes) confirms nothing and counts no
failure.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

from compd.core.adaptation import ProbeReading, ProbeStage
from compd.core.events import Event, EventName
from compd.core.faults import FaultState
from compd.core.health import (
    WRITE_FAULT_AFTER,
    Cause,
    Decision,
    HealthView,
    OutputHealth,
    output_cause,
    recorded_state,
    status_word,
)
from compd.core.modelstep import ModelStepper, finite_or_none
from compd.core.output import OutputStage, Readback
from compd.core.params import CycleParams, params_from_config
from compd.core.plan import WRITTEN, AdaptationView, Outcome, Plan, Row, Snapshot
from compd.core.validation import Validator
from drivers.base import Sample
from models.compensation import CompensationModel

#: the heartbeat counts 0 .. HEARTBEAT_MODULO - 1 and wraps, so it fits an INT, WORD,
#: int16/uint16 or PMC word (the config checks each heartbeat address holds it)
HEARTBEAT_MODULO = 32768

#: a model output beyond this many times limit_um is a fault (hold, then ramp,
#: alarm: MODEL_RANGE), not a value to clamp quietly: a model that far off is
#: broken (a thermal model near its limit may overshoot it, not by 5×)
MODEL_RANGE_FACTOR = 5.0

__all__ = ["HEARTBEAT_MODULO", "MODEL_RANGE_FACTOR", "WRITE_FAULT_AFTER", "WRITTEN", "Cycle",
           "CycleParams", "CycleResult", "Outcome", "Plan", "Row", "offset_in_force",
           "params_from_config"]

#: the name the shell used for a committed cycle before plan/commit
CycleResult = Row


def offset_in_force(*, cause: Cause, confirmed: bool) -> bool:
    """Whether a cycle is COMPLETE: the offset compd wants is the offset in force.

    `cause`: the cycle's (`compd.core.health.output_cause`; healthy only with
    valid inputs, the model stepped and state "ok"); `confirmed`: the controller
    acknowledged this cycle's offset write. A held, faulted, stopped, holding,
    ramping, shutting-down or clamped output is not what the model asks for,
    however busy the loop; an operator's hold is what the operator asks for."""
    return confirmed and cause.healthy


@dataclass(frozen=True, slots=True)
class _Inputs:
    """This cycle's channels: values (NaN when missing), why each is invalid."""

    values: dict[str, float]
    validity: dict[str, str | None]
    #: every channel the live model reads is valid
    valid: bool


@dataclass(frozen=True, slots=True)
class _Stepped:
    """What the model made of the inputs."""

    model_um: float | None = None
    shadow_um: float | None = None
    #: inputs valid, the model stepped to a finite value within its range
    valid: bool = False
    model_invalid: bool = False
    model_range: bool = False
    #: the channel whose fallback model is in force this cycle (degraded), None: the main
    fallback_for: str | None = None

    def invalid(self, inputs: _Inputs, answered: bool) -> Cause | None:
        """Why the model's output cannot be used this cycle (None: it can)."""
        if self.valid:
            return None
        if self.model_range:  # the live model's, or a fallback's in force
            return Cause.MODEL_OUT_OF_RANGE
        if not inputs.valid:
            return Cause.INPUTS_INVALID if answered else Cause.CONTROLLER_NOT_ANSWERING
        return Cause.MODEL_NON_FINITE if self.model_invalid else Cause.INPUTS_INVALID


def _output_stage(params: CycleParams, offset_um: float | None) -> OutputStage:
    """The output stage, believed to hold `offset_um` (the checkpoint's)."""
    stage = OutputStage(
        limit_um=params.limit_um, slew_um_s=params.slew_um_s,
        deadband_um=params.deadband_um, sign=params.sign,
        units_per_um=params.units_per_um, max_dt_s=2.0 * params.period_s,
        initial_um=offset_um if offset_um is not None else 0.0,
        quantum_um=params.offset_quantum_um)
    # what the controller is known to hold at start: the checkpoint's last
    # confirmed offset; without one and without read-back, 0 (a first start
    # can assume nothing else, and a refused first write must fall back to
    # it, not to a value never written); with read-back, unknown until read
    if (offset_um is not None and math.isfinite(offset_um)) or not params.readback:
        stage.confirm()
    return stage


class Cycle:
    """See the module docstring."""

    def __init__(self, params: CycleParams, model: CompensationModel,
                 shadow: CompensationModel | None = None, *,
                 model_state: Mapping[str, Any] | None = None,
                 shadow_state: Mapping[str, Any] | None = None,
                 references: Mapping[str, float] | None = None,
                 offset_um: float | None = None, sequence: int = 0,
                 heartbeat: int = 0,
                 adaptation_state: Mapping[str, Any] | None = None,
                 operator_hold: bool = False,
                 stale_state: Mapping[str, Any] | None = None,
                 stale_age_s: float | None = None,
                 zero: Mapping[str, Any] | None = None,
                 fallback_states: Mapping[str, Any] | None = None) -> None:
        self.params = params
        self.validator = Validator(params.channels, params.time_scale)
        self.health = OutputHealth(params.hold_s, operator_hold=operator_hold)
        self.output = _output_stage(params, offset_um)
        self.sequence = sequence
        self.heartbeat = heartbeat % HEARTBEAT_MODULO
        self.gate = sorted(model.channels)
        self._last_now: float | None = None
        self._invalid: dict[str, str] = {}
        self._mismatch_noted = False
        #: the plan the shell has not committed yet
        self._planned: Plan | None = None
        #: events for the next plan (a write fault that ended)
        self._later: list[Event] = []
        self.probes = self._probe_stage(len(model.terms), adaptation_state)
        #: the output is beyond ±limit_um (told once each way, `_note_limit`)
        self._beyond_noted = False
        self._note_limit(self._later)
        self.models = ModelStepper(model, shadow, model_state=model_state,
                                   shadow_state=shadow_state, references=references,
                                   stale_state=stale_state, stale_age_s=stale_age_s, zero=zero,
                                   fallback_states=fallback_states)
        #: each channel the model reads at its last valid value (the live model steps
        #: on it while a fallback stands in for that channel)
        self._last_valid: dict[str, float] = {}
        #: the channel whose fallback is in force (events on change), None: the main model
        self.fallback_for: str | None = None
        #: the permit as last told: "permitted", "waiting", "unreadable" (events on change)
        self._permit = "permitted"
        #: the re-zero input's last readable value (an edge needs a known 0 before it)
        self._rezero_bit: bool | None = None
        #: the target a permit holds back, minus the offset in force (µm), None: none
        self.pending_um: float | None = None

    def _probe_stage(self, n_terms: int,
                     state: Mapping[str, Any] | None) -> ProbeStage | None:
        settings = self.params.adaptation
        if settings is None:
            return None
        try:
            return ProbeStage(settings, n_terms, state)
        except (ValueError, KeyError, TypeError) as exc:
            self._later.append(Event(EventName.ADAPTATION_STATE_REFUSED, {"reason": str(exc)}))
            return ProbeStage(settings, n_terms)

    @property
    def model(self) -> CompensationModel:
        return self.models.model

    @property
    def shadow(self) -> CompensationModel | None:
        return self.models.shadow

    @property
    def operator_hold(self) -> bool:
        return self.health.operator_hold

    @property
    def write_stopped(self) -> bool:
        return self.health.write_stopped

    @property
    def write_fault(self) -> bool:
        return self.health.write_fault

    @property
    def stopped_outputs(self) -> frozenset[str]:
        return frozenset(self.health.stopped_outputs)

    # -- construction from a checkpoint, and across a reload ------------------------------

    @classmethod
    def from_state(cls, params: CycleParams, model: CompensationModel,
                   shadow: CompensationModel | None, state: Mapping[str, Any], *,
                   fresh: bool, same_model: bool = True,
                   age_s: float | None = None) -> Cycle:
        """A cycle continuing `state` (an `export_state()` / checkpoint dict).
        Fresh: the filters resume where they were. Too old (`age_s` machine
        seconds since it was saved) and the same model: the filters are advanced
        from there over `age_s` with the first valid sample's inputs held, or
        start at its steady state (`compd.core.modelstep`). Another model: only
        the references and the last written offset are kept. The re-zero and the
        adaptation estimator resume whenever the model is the same
        (`same_model`), fresh or not; another model clears them."""
        model_state = state.get("model")
        refs: Mapping[str, float] | None = None
        if isinstance(model_state, Mapping):
            r = model_state.get("references")
            refs = r if isinstance(r, Mapping) and r else None
        elif isinstance(state.get("references"), Mapping):
            refs = state["references"]
        offset = state.get("offset_um")
        offset_um = float(offset) if isinstance(offset, int | float) else None
        usable = fresh and isinstance(model_state, Mapping) and "terms" in model_state
        shadow_state = state.get("shadow") if usable else None
        fallback_states = state.get("fallbacks") if usable else None
        adapted = state.get("adaptation") if same_model else None
        stale = model_state if (not usable and same_model and isinstance(model_state, Mapping)
                                and "terms" in model_state) else None
        zero = state.get("zero")
        cycle = cls(params, model, shadow,
                    model_state=model_state if usable else None,
                    shadow_state=shadow_state if isinstance(shadow_state, Mapping) else None,
                    references=refs, offset_um=offset_um,
                    sequence=int(state.get("sequence", 0)),
                    heartbeat=int(state.get("heartbeat", 0)),
                    adaptation_state=adapted if isinstance(adapted, Mapping) else None,
                    operator_hold=state.get("operator_hold") is True,
                    stale_state=stale, stale_age_s=age_s,
                    zero=zero if isinstance(zero, Mapping) else None,
                    fallback_states=fallback_states if isinstance(fallback_states, Mapping)
                    else None)
        if not same_model:
            dropped = cycle.models.drop_zero("another model")
            if dropped is not None:
                cycle._later.append(dropped)
        return cycle

    def carry_over(self, old: Cycle, *, same_outputs: bool) -> None:
        """Continue `old` across a reload (this cycle built by `from_state` from
        `old.export_state()`): the fault policy's timer and state go on (a hold
        still ramps on time), so does the validator's history while the
        channels are the same, and the stopped outputs while the outputs
        (`same_outputs`: their addresses too) are."""
        self.health.carry_over(old.health, outputs_same=same_outputs)
        if self.params.channels == old.params.channels:
            self.validator = old.validator

    def export_state(self) -> dict[str, Any]:
        """Everything a restart needs (the checkpoint's payload)."""
        out: dict[str, Any] = {
            # the last value the controller is known to hold (None: unknown, read-back
            # will tell), never an output it has not confirmed: a restart takes it as
            # confirmed and slews from it
            "offset_um": self.output.confirmed_um,
            "sequence": self.sequence,
            "heartbeat": self.heartbeat,
        }
        out.update(self.models.export_state())
        if self.probes is not None:
            out["adaptation"] = self.probes.export_state()
        if self.health.operator_hold:
            out["operator_hold"] = True
        return out

    # -- commands -------------------------------------------------------------------------

    def set_operator_hold(self, on: bool, who: str) -> Event | None:
        """An operator's hold (on) or its release (off). While held, a cycle
        that would track the model keeps the offset where it is (faults still
        hold and ramp as always); released, the output slews back to the model
        at the slew limit. Returns the event to log, None when nothing changed."""
        if on == self.health.operator_hold:
            return None
        self.health.operator_hold = on
        return Event(EventName.OPERATOR_HOLD if on else EventName.OPERATOR_RELEASE, {"by": who})

    def rezero(self, who: str, wall_s: float | None = None) -> Event:
        """Take the present prediction as the new zero (an operator at tool
        touch-off): from the next cycle on the target is the growth since now; the
        output stage ramps the offset to it at the slew limit, never a step.
        REZERO, or REZERO_REFUSED before the model has predicted anything."""
        return self.models.rezero(who, wall_s)

    def begin_shutdown(self) -> None:
        """Ramp-to-zero shutdown: from now on the target is 0."""
        self.health.shutting_down = True

    # -- the cycle: plan ------------------------------------------------------------------

    def plan(self, now_s: float, samples: Mapping[str, Sample] | None,
             readback_offset_um: float | None = None, *,
             wall_s: float | None = None, probe: ProbeReading | None = None,
             controller_off: str | None = None, permitted: bool | None = True,
             rezero_bit: bool | None = None) -> Plan:
        """Decide one cycle at machine time `now_s`. `samples` None: the read failed.
        `readback_offset_um`: the controller's offset as read (controller units).
        `probe`: the measuring cycle's values as read (`compd.core.adaptation`).
        `controller_off`: why the controller takes no offset now (module, step 4).
        `permitted`: the controller lets the offset change (None: unreadable, not
        permitted); `rezero_bit`: the re-zero input as read (None: unreadable)."""
        self.sequence += 1
        events, self._later = self._later, []
        dt = self.params.period_s if self._last_now is None else now_s - self._last_now
        was_off = self.health.controller(controller_off, self.output.current_um, events)
        if controller_off is not None:
            pass  # what it holds is not judged while it takes none
        elif was_off is not None:
            self._controller_on(was_off, readback_offset_um, events)
        elif readback_offset_um is not None:
            self._readback(readback_offset_um, events)
        inputs = self._inputs(now_s, samples, wall_s, events)
        stepped = self._step_models(inputs, events, answered=samples is not None)
        self._note_fallback(stepped, events)
        self._rezero_edge(rezero_bit, wall_s, events)
        correction = self._adapt(dt, probe, stepped, events)
        worse = self.probes is not None and self.probes.model_worse \
            and self.probes.settings.guard_acts
        # the probes showed the compensation worse than none: a fault, like a model
        # out of range (hold, then ramp to zero per [faults]), latched; with
        # guard_action = "report" only the event, the page and the metric say so
        why = Cause.MODEL_WORSE_THAN_NONE if worse \
            else stepped.invalid(inputs, answered=samples is not None)
        valid = why is None
        target_um = stepped.model_um + correction if stepped.model_um is not None else None
        decision = self.health.decide(now_s, why, target_um, events)
        permit = self._permit_cause(permitted, decision, events)
        offset_um = self._move_output(decision, dt, held_for_permit=permit is not None)
        self._note_limit(events)
        # only once the stage has moved: a plan that raised before this (the shell then
        # plans again as a failed read) leaves the interval to that one, so a hold still ramps
        self._last_now = now_s
        if valid:
            self.heartbeat = (self.heartbeat + 1) % HEARTBEAT_MODULO
        view = self._view(decision, stepped, worse, why, permit,
                          no_readback=self.params.readback and readback_offset_um is None)
        status = int(status_word(view))
        cause = output_cause(view)
        if self.health.foreign:  # its alarm lasts until the output has ramped to its target
            self.health.foreign = self.output.slewing or self.output.held
        writes, offset_um = self._writes(readback_offset_um, offset_um, status, events)
        recorded = self.params.record_model
        self._planned = Plan(
            sequence=self.sequence, machine_s=now_s,
            wall_s=math.nan if wall_s is None else wall_s, writes=MappingProxyType(writes),
            stage_um=offset_um,
            sent_um=offset_um if self.params.offset_name in writes else None,
            model_um=stepped.model_um if recorded else None, shadow_um=stepped.shadow_um,
            state=recorded_state(view), status=status, heartbeat=self.heartbeat,
            inputs_valid=valid, cause=cause,
            channels=MappingProxyType({n: finite_or_none(v) for n, v in inputs.values.items()}),
            validity=MappingProxyType(inputs.validity),
            contributions=MappingProxyType(self._contributions(stepped, valid)),
            probe=self._probe_record(), events=tuple(events),
            shutdown_done=self._shutdown_done(offset_um))
        return self._planned

    def _inputs(self, now_s: float, samples: Mapping[str, Sample] | None,
                wall_s: float | None, events: list[Event]) -> _Inputs:
        validity = self.validator.check(now_s, samples, wall_s)
        self._note_validity(validity, events)
        got = samples or {}
        values = {n: (float(s.value) if (s := got.get(n)) is not None else math.nan)
                  for n in self.params.channels}
        return _Inputs(values, validity, all(validity.get(ch) is None for ch in self.gate))

    def _step_models(self, inputs: _Inputs, events: list[Event], *,
                     answered: bool) -> _Stepped:
        if not answered:
            return _Stepped()
        valid = {ch for ch in self.gate if inputs.validity.get(ch) is None}
        self.models.step_fallbacks(inputs.values, valid, events)
        if not inputs.valid:
            return self._step_degraded(inputs, valid, events)
        self._last_valid.update((ch, inputs.values[ch]) for ch in valid)
        model_um = self.models.step(inputs.values, events)
        if model_um is None:
            return _Stepped(model_invalid=True)
        if self._model_out_of_range(model_um, events):
            return _Stepped(model_um=model_um, model_range=True)
        shadow_um = self.models.step_shadow(inputs.values, events)
        return _Stepped(model_um=model_um, shadow_um=shadow_um, valid=True)

    def _step_degraded(self, inputs: _Inputs, valid: set[str],
                       events: list[Event]) -> _Stepped:
        """One channel the model reads is invalid and its fallback was stepped: the
        fallback's output is the model's this cycle (`compd.core.fallback`); else
        nothing stepped (the fault policy holds, then ramps). The live model keeps
        stepping with the lost channel at its last valid value, so every other term
        is current when the channel returns; its output is not used meanwhile."""
        bank = self.models.fallbacks
        lost = bank.in_force([ch for ch in self.gate if ch not in valid])
        fallback_um = bank.output_um(lost) if lost is not None else None
        if lost is None or fallback_um is None:
            return _Stepped()
        self._last_valid.update((ch, inputs.values[ch]) for ch in valid)
        if self.models.model_ready and lost in self._last_valid:
            self.models.step({**inputs.values, lost: self._last_valid[lost]}, events)
        if self._model_out_of_range(fallback_um, events):
            return _Stepped(model_um=fallback_um, model_range=True)
        return _Stepped(model_um=fallback_um, valid=True, fallback_for=lost)

    def _note_fallback(self, stepped: _Stepped, events: list[Event]) -> None:
        """Tell when a fallback comes into force, and when it leaves."""
        was, now = self.fallback_for, stepped.fallback_for
        if was == now:
            return
        if was is not None:
            events.append(Event(EventName.FALLBACK_ENDED, {
                "lost": was, "now": "main model" if stepped.valid and now is None
                else (f"fallback for {now}" if now is not None else "none: hold, then ramp")}))
        if now is not None:
            events.append(Event(EventName.FALLBACK_IN_FORCE, {
                "lost": now, "reason": self._invalid.get(now), "fallback_um": stepped.model_um,
                "offset_um": self.output.current_um, "slew_um_s": self.output.slew_um_s}))
        self.fallback_for = now

    def _move_output(self, decision: Decision, dt: float, *, held_for_permit: bool) -> float:
        target = self.output.current_um if decision.target_um is None else decision.target_um
        tracking = decision.state == FaultState.OK
        self.pending_um = None
        if self.health.controller_off is not None:  # it takes no offset: stand still
            self.output.slewing = False
            return self.output.current_um
        if held_for_permit and tracking:
            out = self.output
            wanted = max(-out.limit_um, min(out.limit_um, target))
            self.pending_um = wanted - out.current_um
        if (self.health.operator_hold or held_for_permit) and tracking:
            target = self.output.current_um
        return self.output.step(target, dt, deadband=tracking)

    def _permit_cause(self, permitted: bool | None, decision: Decision,
                      events: list[Event]) -> Cause | None:
        """Why a tracking output is held for the controller's permission (None: it is
        not); the events when the permit changes (module docstring, step 4)."""
        if decision.state != FaultState.OK:
            return None  # a fault holds or ramps whatever the permit: nothing to tell
        now = "permitted" if permitted else ("waiting" if permitted is False else "unreadable")
        if now != self._permit:
            if now == "unreadable":
                events.append(Event(EventName.PERMIT_UNREADABLE, {
                    "action": "taken as not permitted: the offset in force is held"}))
            elif now == "waiting":
                events.append(Event(EventName.PERMISSION_WAITING, {
                    "offset_um": self.output.current_um}))
            else:
                target = decision.target_um
                events.append(Event(EventName.PERMISSION_GRANTED, {
                    "offset_um": self.output.current_um,
                    "pending_um": None if target is None else target - self.output.current_um,
                    "slew_um_s": self.output.slew_um_s}))
            self._permit = now
        if now == "permitted":
            return None
        return Cause.WAITING_FOR_PERMISSION if now == "waiting" else Cause.PERMIT_UNREADABLE

    def _rezero_edge(self, bit: bool | None, wall_s: float | None,
                     events: list[Event]) -> None:
        """The re-zero input's rising edge (a known 0, then 1) re-zeroes; an
        unreadable value is no edge, and the next readable one starts afresh."""
        was, self._rezero_bit = self._rezero_bit, bit
        if bit and was is False:
            events.append(self.rezero("controller input [output] rezero", wall_s))

    def _view(self, decision: Decision, stepped: _Stepped, worse: bool, why: Cause | None,
              permit: Cause | None, *, no_readback: bool) -> HealthView:
        h, out = self.health, self.output
        target = decision.target_um
        return HealthView(
            policy=decision.state, alarm=decision.alarm, write_stopped=h.write_stopped,
            write_fault=h.write_fault, held=out.held, foreign=h.foreign,
            operator_hold=h.operator_hold, slewing=out.slewing,
            model_invalid=stepped.model_invalid, model_range=stepped.model_range,
            model_worse=worse, controller_off=h.controller_off is not None, invalid=why,
            degraded=stepped.fallback_for is not None,
            no_readback=no_readback,
            at_limit=target is not None and abs(target) > out.limit_um,
            permit=permit if decision.state == FaultState.OK else None,
            recorder_only=self.params.recorder_only)

    def _writes(self, readback_offset_um: float | None, offset_um: float, status: int,
                events: list[Event]) -> tuple[dict[str, float], float]:
        """The writes of this cycle, and the offset they leave in force (µm)."""
        p = self.params
        writes: dict[str, float] = {}
        if p.recorder_only:  # nothing at all reaches the controller
            return writes, offset_um
        h = self.health
        if not h.write_stopped and not self.output.held and h.controller_off is None:
            if p.readback and readback_offset_um is None:
                # the controller still holds what it last confirmed: start from there
                self.output.revert()
                offset_um = self.output.current_um
                if not self._mismatch_noted:
                    events.append(Event(EventName.OFFSET_WRITE_SKIPPED, {"reason": "no_readback"}))
                    self._mismatch_noted = True
            else:
                self._mismatch_noted = False
                writes[p.offset_name] = self.output.to_controller(offset_um)
        stopped = self.health.stopped_outputs
        if p.heartbeat_name and p.heartbeat_name not in stopped:
            writes[p.heartbeat_name] = float(self.heartbeat)
        if p.status_name and p.status_name not in stopped:
            writes[p.status_name] = float(status)
        return writes, offset_um

    def _contributions(self, stepped: _Stepped, valid: bool) -> dict[str, float]:
        """Each term's contribution as recorded, with the fallback's, the shadow's
        and the adaptation's totals."""
        recorded = self.params.record_model
        contributions = self.models.contributions() if valid and recorded else {}
        if stepped.fallback_for is not None and stepped.model_um is not None and recorded:
            contributions["fallback_total"] = stepped.model_um
        if stepped.shadow_um is not None:
            contributions["shadow_total"] = stepped.shadow_um
        if self.probes is not None and valid:
            contributions["adaptation"] = self.probes.correction_um
        return contributions

    def _probe_record(self) -> Mapping[str, Any] | None:
        last = self.probes.last if self.probes is not None else None
        return None if last is None else MappingProxyType(dict(last))

    def _shutdown_done(self, offset_um: float) -> bool:
        h = self.health
        if h.shutting_down and self.params.recorder_only:
            return True  # nothing was written: nothing to ramp
        return h.shutting_down and (offset_um == 0.0 or h.write_stopped or self.output.held
                                    or h.controller_off is not None)

    # -- the cycle: commit ----------------------------------------------------------------

    def commit(self, outcome: Outcome = WRITTEN) -> Row:
        """Close the planned cycle with how its writes went; its report."""
        plan, self._planned = self._planned, None
        if plan is None:
            raise RuntimeError("commit() without a plan(): one commit per plan")
        offset_sent = plan.sent_um is not None
        in_force = False
        events: tuple[Event, ...] = ()
        if outcome.ok:
            if offset_sent:
                self.output.confirm()
                in_force = offset_in_force(cause=plan.cause, confirmed=True)
                self.health.write_succeeded(self._later)
            elif self.params.recorder_only:  # recorded is what such a run is for
                in_force = plan.cause.healthy
        else:
            if offset_sent:  # retried next cycle from the confirmed value
                self.output.revert()
            events = tuple(self.health.write_failed(
                outcome.outputs, permanent=outcome.permanent, reason=outcome.reason,
                offset_failed=offset_sent, offset_name=self.params.offset_name,
                offset_um=self.output.current_um))
        cause = self.health.committed_cause(plan.cause,
                                            offset_failed=offset_sent and not outcome.ok)
        return Row(
            sequence=plan.sequence, machine_s=plan.machine_s, wall_s=plan.wall_s,
            writes=plan.writes, stage_um=plan.stage_um, sent_um=plan.sent_um,
            write_ok=outcome.ok, confirmed_um=self.output.confirmed_um,
            model_um=plan.model_um, shadow_um=plan.shadow_um, state=plan.state,
            status=plan.status, heartbeat=plan.heartbeat, inputs_valid=plan.inputs_valid,
            in_force=in_force, cause=cause, channels=plan.channels, validity=plan.validity,
            contributions=plan.contributions, probe=plan.probe, snapshot=self._snapshot(),
            events=plan.events, write_events=events, shutdown_done=plan.shutdown_done)

    def _snapshot(self) -> Snapshot:
        adaptation = None
        probes = self.probes
        if probes is not None:
            est = probes.adapter
            adaptation = AdaptationView(est.estimated_bias_um, est.bias_sigma_um,
                                        probes.correction_um, est.standing_down,
                                        probes.model_worse, guard_probes=len(probes.guard),
                                        guard_worse=probes.guard_worse,
                                        probes_accepted=probes.accepted,
                                        probes_refused=probes.refused,
                                        gate_refusals=probes.gate_refusals)
        m = self.models
        # the stepper replaces its references, never changes them in place: a
        # read-only view of the dict in force is the snapshot's
        refs = m.references
        return Snapshot(self.health.operator_hold, adaptation, pending_um=self.pending_um,
                        zero_um=m.zero_um if m.zero_by else None,
                        model_start=m.init_mode, reference=m.reference_source,
                        fallback_for=self.fallback_for,
                        references=None if refs is None else MappingProxyType(refs))

    # -- internals ------------------------------------------------------------------------

    def _readback(self, value: float, events: list[Event]) -> None:
        out = self.output
        rb_um = out.from_controller(value) if math.isfinite(value) else math.nan
        was_held, expected = out.held, out.confirmed_um
        seen = out.observe(rb_um, self.params.readback_tolerance_um)
        if seen is Readback.OUT_OF_RANGE:
            if not was_held:
                events.append(Event(EventName.READBACK_OUT_OF_RANGE, {
                    "expected_um": expected, "readback_um": finite_or_none(rb_um),
                    "limit_um": out.limit_um, "action": "offset writes held"}))
            self.health.foreign = True
            return
        if was_held:
            events.append(Event(EventName.READBACK_IN_RANGE, {
                "readback_um": rb_um, "action": "ramping from it"}))
            self.health.foreign = True
        if seen is Readback.ADOPTED:
            events.append(Event(EventName.READBACK_ADOPTED, {"offset_um": out.current_um}))
        elif seen is Readback.FOREIGN:
            events.append(Event(EventName.READBACK_MISMATCH, {
                "expected_um": expected, "readback_um": rb_um, "action": "ramping from it"}))
            self.health.foreign = True

    def _controller_on(self, was: str, value: float | None, events: list[Event]) -> None:
        """The controller takes offsets again: what it holds now (LinuxCNC zeroes
        its offset at machine on) is the start, no alarm, ramped from at the slew
        limit; a value beyond ±limit, or one after a held offset, is judged as
        any read-back."""
        rb_um = (self.output.from_controller(value)
                 if value is not None and math.isfinite(value) else None)
        if rb_um is not None and abs(rb_um) <= self.output.limit_um and not self.output.held:
            self.output.adopt(rb_um)
        elif value is not None:
            self._readback(value, events)
        events.append(Event(EventName.CONTROLLER_ON, {"was": was, "readback_um": rb_um}))

    def _note_limit(self, events: list[Event]) -> None:
        """The offset compd wrote is beyond ±limit_um (a limit lowered by a reload or
        a restart; `OutputStage.beyond_limit`): it ramps into it at the slew limit;
        told when it is found, and when it is within."""
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

    def _model_out_of_range(self, model_um: float, events: list[Event]) -> bool:
        """A model output beyond MODEL_RANGE_FACTOR·limit_um is a broken model,
        not a value to clamp: a fault (hold, then ramp) with an alarm."""
        bound = MODEL_RANGE_FACTOR * self.params.limit_um
        out = abs(model_um) > bound
        if out != self.health.model_range:
            self.health.model_range = out
            events.append(Event(EventName.MODEL_OUT_OF_RANGE if out else EventName.MODEL_IN_RANGE, {
                "model_um": model_um, "bound_um": bound}))
        return out

    def _note_validity(self, validity: Mapping[str, str | None], events: list[Event]) -> None:
        for name, reason in validity.items():
            before = self._invalid.get(name)
            if reason is not None and reason != before:
                self._invalid[name] = reason
                events.append(Event(EventName.CHANNEL_INVALID, {"channel": name, "reason": reason}))
            elif reason is None and before is not None:
                del self._invalid[name]
                events.append(Event(EventName.CHANNEL_VALID, {"channel": name, "was": before}))

    def _adapt(self, dt: float, probe: ProbeReading | None, stepped: _Stepped,
               events: list[Event]) -> float:
        """The adaptation's correction to add to the model output (0 when off,
        in shadow mode, or while the cycle is not valid)."""
        if self.probes is None:
            return 0.0
        valid = stepped.valid and stepped.fallback_for is None  # the live model's own cycle
        terms = self.model.contributions if valid else []
        correction = self.probes.step(dt, probe, complete=valid, model_um=stepped.model_um,
                                      terms_um=terms, offset_in_force_um=self.output.confirmed_um,
                                      events=events)
        return correction if valid else 0.0
