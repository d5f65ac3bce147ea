"""The sample cycle, sans I/O: samples and the time in; writes, events and the
record row out. No asyncio, no logging, no clock of its own, so hours of
machine time are tested in milliseconds with a fake clock.

Two calls per cycle (the shape of h11: the core decides, the shell does the
I/O): `Cycle.plan(now_s, samples, readback_offset_um) -> Plan` decides what
to write; the shell writes `plan.writes` and reports how that went with
`Cycle.commit(outcome) -> Row`, the cycle's report (frozen; whether the
controller confirmed the offset is in it). `plan`:

1. read-back (`compd.core.readback`): the controller's offset judged against
   the value it last confirmed; a foreign value is an alarm, one beyond
   ±limit_um holds the writes;
2. validate every channel and 3. step the models, the fallbacks and the
   shadow (`compd.core.stepping`); a model output far beyond the limit is a
   fault;
4. the output's health (`compd.core.health`: the fault policy and every
   other state) picks the target; the output stage (`compd.core.output`)
   makes it safe; the status word is a pure function of the health.
   While the controller says it takes no offset (``controller_off``: machine
   off, E-stop; `[output] machine_on`/`estop`) the output stage stands still
   and no offset is written (status CONTROLLER_OFF and HOLDING, state "hold");
   the model keeps stepping. While the controller withholds its permission
   a tracking output holds, and the re-zero input's rising edge re-zeroes
   (`compd.core.permit`);
5. writes: nothing at all in a recorder-only run (``params.recorder_only``:
   ``[output] enabled = false`` or no ``[model]``: no offset, heartbeat or
   status; cause RECORDER_ONLY while the inputs are valid, and a cycle whose
   inputs were valid and recorded is its complete one); else the offset
   (in controller units; omitted once the controller
   refused it permanently, and while read-back is configured but the read
   failed, since then the controller's state is unknown), the heartbeat
   (advanced only on a complete valid cycle of the offset's model: it says
   nothing about the per-axis lines), the status word and, with per-axis
   lines, the axes word (`compd.core.axis_bank.AxisBank.status_word`: which axes
   are in force, and a life bit that toggles every cycle).

Each cycle names why the offset compd wants is not in force, or that it is
(`compd.core.health.Cause`, `Plan.cause` and after the write `Row.cause`):
health, the status page, the metrics, the OPC UA face and the fault events'
``reason`` all read it. A cycle is COMPLETE (`offset_in_force`: the one
definition, used by the daemon's metrics, the checkpoint that `compd health
--state-dir` reads, and the recorder's ``complete`` column) only when its
cause is healthy (in force, or an operator's hold: inputs valid and the
model stepped, state "ok", no foreign offset, write fault, stopped writes,
fault hold, ramp, shutdown or limit) and the controller confirmed this
cycle's offset write (`commit(WRITTEN)`): `Row.in_force`. `Row.inputs_valid`
is the narrower "inputs valid, model stepped" that advances the heartbeat.

WRITE_FAULT_AFTER offset writes failing in a row are a write fault (WRITE_FAULT
and ALARM, state "write_fault") until one succeeds. The report keeps the
stage's value (`stage_um`), what was sent (`sent_um`) and what the controller
confirmed holding (`confirmed_um`) apart (`compd.core.plan.Row`). A plan that is never
committed (a test stepping without writes) confirms nothing and counts no
failure.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from types import MappingProxyType
from typing import Any

from compd.core.adaptation import ProbeReading
from compd.core.axis_bank import AxisBank
from compd.core.axis_params import AxisRow
from compd.core.events import Event, EventName
from compd.core.faults import FaultState
from compd.core.health import WRITE_FAULT_AFTER, Cause, Decision, OutputHealth
from compd.core.health_view import HealthView, output_cause, recorded_state, status_bits
from compd.core.modelstep import ModelStepper, finite_or_none
from compd.core.params import CycleParams, params_from_config
from compd.core.permit import Permit, RezeroEdge
from compd.core.plan import NO_AXES, WRITTEN, Outcome, Plan, Row
from compd.core.readback import ReadBack
from compd.core.restore import output_stage, probe_stage, restore_arguments
from compd.core.snapshot import probe_record, recorded_contributions, take_snapshot
from compd.core.stepping import MODEL_RANGE_FACTOR, Inputs, Stepped, Stepping
from drivers.base import Sample
from models.compensation import CompensationModel

#: the heartbeat counts 0 .. HEARTBEAT_MODULO - 1 and wraps, so it fits an INT, WORD,
#: int16/uint16 or PMC word (the config checks each heartbeat address holds it)
HEARTBEAT_MODULO = 32768

__all__ = ["HEARTBEAT_MODULO", "MODEL_RANGE_FACTOR", "WRITE_FAULT_AFTER", "WRITTEN", "Cycle",
           "CycleParams", "Outcome", "Plan", "Row", "offset_in_force",
           "params_from_config"]


def offset_in_force(*, cause: Cause, confirmed: bool) -> bool:
    """Whether a cycle is COMPLETE: the offset compd wants is the offset in force.

    `cause`: the cycle's (`compd.core.health_view.output_cause`; healthy only with
    valid inputs, the model stepped and state "ok"); `confirmed`: the controller
    acknowledged this cycle's offset write. A held, faulted, stopped, holding,
    ramping, shutting-down or clamped output is not what the model asks for,
    however busy the loop; an operator's hold is what the operator asks for."""
    return confirmed and cause.healthy


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
                 fallback_states: Mapping[str, Any] | None = None,
                 axes_state: Mapping[str, Any] | None = None) -> None:
        self.params = params
        self.health = OutputHealth(params.hold_s, operator_hold=operator_hold)
        self.output = output_stage(params, offset_um)
        self.readback = ReadBack(self.output, self.health, params.readback_tolerance_um)
        self.sequence = sequence
        self.heartbeat = heartbeat % HEARTBEAT_MODULO
        self._last_now: float | None = None
        #: the plan the shell has not committed yet
        self._planned: Plan | None = None
        #: events for the next plan (a write fault that ended)
        self._later: list[Event] = []
        self.probes = probe_stage(params.adaptation, len(model.terms), adaptation_state,
                                  self._later)
        self.readback.note_limit(self._later)
        self.models = ModelStepper(model, shadow, model_state=model_state,
                                   shadow_state=shadow_state, references=references,
                                   stale_state=stale_state, stale_age_s=stale_age_s, zero=zero,
                                   fallback_states=fallback_states)
        self.stepping = Stepping(params, self.models, sorted(model.channels), self.health)
        self.permit = Permit()
        self.rezero_edge = RezeroEdge()
        #: the target a permit holds back, minus the offset in force (µm), None: none
        self.pending_um: float | None = None
        #: [output.axes]: each axis's line, a separate output of this cycle
        self.axes = AxisBank(params.axes, hold_s=params.hold_s, period_s=params.period_s,
                             readback=params.readback, state=axes_state)

    # -- construction from a checkpoint, and across a reload ------------------------------

    @classmethod
    def from_state(cls, params: CycleParams, model: CompensationModel,
                   shadow: CompensationModel | None, state: Mapping[str, Any], *,
                   fresh: bool, same_model: bool = True,
                   age_s: float | None = None) -> Cycle:
        """A cycle continuing `state` (an `export_state()` / checkpoint dict;
        what is kept when it is fresh, too old or another model's:
        `compd.core.restore`)."""
        cycle = cls(params, model, shadow, **restore_arguments(
            state, fresh=fresh, same_model=same_model, age_s=age_s))
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
        (`same_outputs`: their addresses too) are; each axis's likewise
        (`compd.core.axis_bank.AxisBank.carry_over`)."""
        self.health.carry_over(old.health, outputs_same=same_outputs)
        self.axes.carry_over(old.axes, same_outputs=same_outputs)
        if self.params.channels == old.params.channels:
            self.stepping.validator = old.stepping.validator

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
        if self.axes:
            out["axes"] = self.axes.export_state()
        return out

    # -- commands -------------------------------------------------------------------------

    def set_operator_hold(self, on: bool, who: str) -> Event | None:
        """An operator's hold (on) or its release (off). While held, a cycle
        that would track the model keeps the offset where it is (faults still
        hold and ramp as always); released, the output slews back to the model
        at the slew limit. Returns the event to log, None when nothing changed."""
        if not self.health.set_operator_hold(on):
            return None
        return Event(EventName.OPERATOR_HOLD if on else EventName.OPERATOR_RELEASE, {"by": who})

    def rezero(self, who: str, wall_s: float | None = None) -> Event:
        """Take the present prediction as the new zero (an operator at tool
        touch-off): from the next cycle on the target is the growth since now; the
        output stage ramps the offset to it at the slew limit, never a step.
        REZERO, or REZERO_REFUSED before the model has predicted anything."""
        return self.models.rezero(who, wall_s)

    def begin_shutdown(self) -> None:
        """Ramp-to-zero shutdown: from now on the target is 0."""
        self.health.begin_shutdown()
        self.axes.begin_shutdown()

    # -- the cycle: plan ------------------------------------------------------------------

    def plan(self, now_s: float, samples: Mapping[str, Sample] | None,
             readback_offset_um: float | None = None, *,
             wall_s: float | None = None, probe: ProbeReading | None = None,
             controller_off: str | None = None, permitted: bool | None = True,
             rezero_bit: bool | None = None,
             axes_readback: Mapping[str, float | None] | None = None) -> Plan:
        """Decide one cycle at machine time `now_s`. `samples` None: the read failed.
        `readback_offset_um`: the controller's offset as read (controller units).
        `probe`: the measuring cycle's values as read (`compd.core.adaptation`).
        `controller_off`: why the controller takes no offset now (module, step 4).
        `permitted`: the controller lets the offset change (None: unreadable, not
        permitted); `rezero_bit`: the re-zero input as read (None: unreadable).
        `axes_readback`: each axis parameter as read (`compd.core.axes`; None: not
        read, a value None: that one not read)."""
        self.sequence += 1
        events, self._later = self._later, []
        dt = self.params.period_s if self._last_now is None else now_s - self._last_now
        was_off = self.health.controller(controller_off, self.output.current_um, events)
        self.readback.judge(readback_offset_um, off=controller_off, was_off=was_off,
                            events=events)
        answered = samples is not None
        inputs = self.stepping.inputs(now_s, samples, wall_s, events)
        stepped = self.stepping.step(inputs, events, answered=answered)
        self.stepping.note_fallback(stepped, self.output, events)
        if self.rezero_edge.rising(rezero_bit):
            events.append(self.rezero("controller input [output] rezero", wall_s))
        correction = self._adapt(dt, probe, stepped, events)
        worse = self.probes is not None and self.probes.model_worse \
            and self.probes.settings.guard_acts
        # the probes showed the compensation worse than none: a fault, like a model
        # out of range (hold, then ramp to zero per [faults]), latched; with
        # guard_action = "report" only the event, the page and the metric say so
        why = Cause.MODEL_WORSE_THAN_NONE if worse else stepped.invalid(inputs, answered)
        target_um = stepped.model_um + correction if stepped.model_um is not None else None
        decision = self.health.decide(now_s, why, target_um, events)
        permit = self.permit.cause(permitted, decision, self.output, events)
        offset_um = self._move_output(decision, dt, held_for_permit=permit is not None)
        self.readback.note_limit(events)
        # only once the stage has moved: a plan that raised before this (the shell then
        # plans again as a failed read) leaves the interval to that one, so a hold still ramps
        self._last_now = now_s
        if why is None:
            self.heartbeat = (self.heartbeat + 1) % HEARTBEAT_MODULO
        view = self._view(decision, stepped, worse, why, permit,
                          no_readback=self.params.readback and readback_offset_um is None)
        # a foreign read-back's alarm lasts until the output has ramped to its target
        self.health.foreign_settled(moving=self.output.slewing or self.output.held)
        status = status_bits(view)
        writes, offset_um = self._writes(readback_offset_um, offset_um, status, events)
        if self.axes:
            writes.update(self.axes.plan(
                now_s, dt, inputs.values, inputs.validity, answered=answered,
                readback=axes_readback, off=controller_off,
                hold=self.health.operator_hold or permit is not None,
                write=not self.params.recorder_only, events=events))
            name = self.params.axes_status_name
            if name and not self.params.recorder_only \
                    and name not in self.health.stopped_outputs:
                writes[name] = float(self.axes.status_word())
        self._planned = self._plan(now_s, wall_s, writes, offset_um, inputs, stepped, view,
                                   status, events)
        return self._planned

    def _plan(self, now_s: float, wall_s: float | None, writes: dict[str, float],
              offset_um: float, inputs: Inputs, stepped: Stepped, view: HealthView,
              status: int, events: list[Event]) -> Plan:
        """The frozen plan of this cycle (its mappings read-only)."""
        valid = view.invalid is None
        recorded = self.params.record_model
        return Plan(
            sequence=self.sequence, machine_s=now_s,
            wall_s=math.nan if wall_s is None else wall_s, writes=MappingProxyType(writes),
            stage_um=offset_um,
            sent_um=offset_um if self.params.offset_name in writes else None,
            model_um=stepped.model_um if recorded else None, shadow_um=stepped.shadow_um,
            state=recorded_state(view), status=status,
            heartbeat=self.heartbeat, inputs_valid=valid, cause=output_cause(view),
            channels=MappingProxyType({n: finite_or_none(v) for n, v in inputs.values.items()}),
            validity=MappingProxyType(inputs.validity),
            contributions=MappingProxyType(recorded_contributions(
                self.models, self.probes, stepped, valid=valid, recorded=recorded)),
            probe=probe_record(self.probes), events=tuple(events),
            shutdown_done=self._shutdown_done(offset_um) and self.axes.settled())

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

    def _view(self, decision: Decision, stepped: Stepped, worse: bool, why: Cause | None,
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
                offset_um = self.readback.skip_write(events)
            else:
                self.readback.written()
                writes[p.offset_name] = self.output.to_controller(offset_um)
        stopped = self.health.stopped_outputs
        if p.heartbeat_name and p.heartbeat_name not in stopped:
            writes[p.heartbeat_name] = float(self.heartbeat)
        if p.status_name and p.status_name not in stopped:
            writes[p.status_name] = float(status)
        return writes, offset_um

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
        axes: Mapping[str, AxisRow] = NO_AXES
        axis_events: tuple[Event, ...] = ()
        if self.axes:
            axes, axis_events = self.axes.commit(outcome.ok, outcome.outputs, outcome.permanent,
                                                 outcome.reason, self._later)
        return Row(
            sequence=plan.sequence, machine_s=plan.machine_s, wall_s=plan.wall_s,
            writes=plan.writes, stage_um=plan.stage_um, sent_um=plan.sent_um,
            write_ok=outcome.ok, confirmed_um=self.output.confirmed_um,
            model_um=plan.model_um, shadow_um=plan.shadow_um, state=plan.state,
            status=plan.status, heartbeat=plan.heartbeat, inputs_valid=plan.inputs_valid,
            in_force=in_force, cause=cause, channels=plan.channels, validity=plan.validity,
            contributions=plan.contributions, probe=plan.probe, snapshot=take_snapshot(
                operator_hold=self.health.operator_hold, probes=self.probes, models=self.models,
                fallback_for=self.stepping.fallback_for, pending_um=self.pending_um),
            events=plan.events, write_events=events + axis_events,
            shutdown_done=plan.shutdown_done, axes=axes)

    # -- internals ------------------------------------------------------------------------

    def _adapt(self, dt: float, probe: ProbeReading | None, stepped: Stepped,
               events: list[Event]) -> float:
        """The adaptation's correction to add to the model output (0 when off,
        in shadow mode, or while the cycle is not valid)."""
        if self.probes is None:
            return 0.0
        valid = stepped.valid and stepped.fallback_for is None  # the live model's own cycle
        terms = self.models.model.contributions if valid else []
        correction = self.probes.step(dt, probe, complete=valid, model_um=stepped.model_um,
                                      terms_um=terms, offset_in_force_um=self.output.confirmed_um,
                                      events=events)
        return correction if valid else 0.0
