"""The per-axis compensation lines, as the cycle drives them (pure).

For a controller that takes each axis's compensation as its own parameters
(a value at a reference position and a slope: `drivers.temp_comp`), each
configured axis (``[output.axes.<axis>]``) is a separate output of the one
cycle: the same read, the same validated inputs, its writes in the same
`Driver.write` as the offset, heartbeat and status. Per axis:

- its value model and its slope model (none: the slope stays 0) step on the
  cycle's inputs, each a `compd.core.modelstep.ModelStepper` of its own;
- the value and the slope each pass their own `compd.core.output.OutputStage`
  (clamp to the axis's limit, rate limit, deadband, the controller's grid),
  and their read-back is judged as the offset's is (`compd.core.readback`): a
  value compd did not write (a second writer, a restarted controller back at 0)
  is an alarm and the stage ramps from it, one beyond the limit holds the
  axis's writes; the reference position is written every cycle and a
  read-back that differs from it is such an alarm too;
- its own `compd.core.health.OutputHealth`: an invalid input of its models, a
  non-finite output or one beyond `MODEL_RANGE_FACTOR` times its limit holds
  that axis, then ramps value and slope to 0 at their rates after
  ``[faults] hold_s`` (the alarm), while the offset and every other axis go on;
  a write refused for one of its parameters counts against that axis alone
  (a permanent refusal stops that axis's writes);
- its state, cause and status word are pure functions of a `HealthView`, as
  the offset's (`compd.core.health_view`): `AxisRow` in the cycle's report.

For a controller without such parameters (a plain offset register over
Modbus, FOCAS), an axis names a position channel instead (`AxisParams.position`)
and the cycle writes one offset per axis, the line evaluated at the position
read this cycle: ``value + slope·(x - reference)/1000`` (µm). Value and slope
still pass their own stages (their changes from the models are rate limited);
the change the axis's motion makes (slope·Δx) passes unlimited, as a
controller applying its own line would, bounded by the slope's limit over the
position channel's range (`AxisParams.offset_limit_um`). The position is a
channel like the temperatures and gates the axis as they do: missing, of bad
quality, not finite, out of range or older than its ``stale_after_s`` holds the
axis at its last written offset (then the alarm's ramp, at the last valid
position). The operator's hold and a controller that does not permit a change
hold the whole offset, the motion's part too. The offset's read-back is judged
as the value's (`AxisOutput.judge`).

The tool direction (``[output.axes.tool]``: SINUMERIK SD42960
``$SC_TOOL_TEMP_COMP``, applied along the tool's orientation) is an axis with a
value only (`AxisParams.value_only`): its model, stage, read-back and health as
any axis's, no slope or reference written; it has no bits in the axes word.

The operator's hold, the controller's permission and the controller's own
state (machine off, E-stop) hold the axes as they hold the offset; a
ramp-to-zero shutdown ramps them too. A re-zero and the fallback models are
the offset's alone.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping
from typing import Any

from compd.core.axis_params import (
    AXIS_RANGE_FACTOR,
    FLOAT_TOLERANCE,
    AxisParams,
    AxisRow,
    ParamRow,
)
from compd.core.events import Event, EventName
from compd.core.faults import FaultState
from compd.core.health import WRITE_FAULT_AFTER, Cause, OutputHealth
from compd.core.health_view import HealthView, output_cause, recorded_state, status_bits
from compd.core.modelstep import ModelStepper, finite_or_none
from compd.core.output import OutputStage
from compd.core.readback import ReadBack
from models.compensation import CompensationModel
from models.errors import ModelError

__all__ = [
    "AXIS_RANGE_FACTOR",
    "WRITE_FAULT_AFTER",
    "AxisOutput",
    "AxisParams",
    "AxisRow",
    "ParamRow",
]

class _Param:
    """One parameter (value or slope): its model, its stage and its read-back."""

    def __init__(self, name: str, model: CompensationModel | None, health: OutputHealth, *,
                 limit: float, slew: float, deadband: float, quantum: float, max_dt_s: float,
                 initial: float | None, readback: bool,
                 state: Mapping[str, Any] | None, fresh: bool) -> None:
        self.name = name
        self.models: ModelStepper | None = None
        if model is not None:
            refs = state.get("references") if state is not None else None
            refs = refs if isinstance(refs, Mapping) and refs else None
            try:
                usable = fresh and state is not None and "terms" in state
                self.models = ModelStepper(model, None, model_state=state if usable else None,
                                           references=refs)
            except (ModelError, TypeError, ValueError, KeyError):
                self.models = ModelStepper(model, None, references=refs)
        self.stage = OutputStage(limit_um=limit, slew_um_s=slew, deadband_um=deadband,
                                 max_dt_s=max_dt_s, quantum_um=quantum,
                                 initial_um=initial if initial is not None else 0.0)
        if initial is not None or not readback:
            self.stage.confirm()
        self.readback = ReadBack(self.stage, health, FLOAT_TOLERANCE)
        self.bound = AXIS_RANGE_FACTOR * limit

    def step(self, values: Mapping[str, float], events: list[Event]) -> float | None:
        if self.models is None:
            return 0.0
        return self.models.step(values, events)


def _tagged(events: list[Event], **tags: Any) -> list[Event]:
    return [Event(e.name, {**tags, **e.fields}) for e in events]


def _invalid_channels(validity: Mapping[str, str | None]) -> list[str]:
    """The channels invalid this cycle (`AxisOutput.plan`'s `invalid`)."""
    return [ch for ch, why in validity.items() if why is not None]


class AxisOutput:
    """One axis's models, stages and health (module docstring)."""

    def __init__(self, p: AxisParams, hold_s: float, period_s: float, readback: bool,
                 state: Mapping[str, Any] | None) -> None:
        self.p = p
        self.health = OutputHealth(hold_s)
        st = state or {}
        dt = 2.0 * period_s
        fresh = st.get("fresh", True) is True

        def initial(key: str) -> float | None:
            v = st.get(key)
            return float(v) if isinstance(v, int | float) and math.isfinite(v) else None

        def model_state(key: str, sha256: str) -> Mapping[str, Any] | None:
            v = st.get(key)
            if not isinstance(v, Mapping):
                return None
            if st.get(f"{key}_sha256", "") != sha256:  # another model's: its references only
                return {"references": v.get("references")}
            return v

        self.value = _Param(p.name("value"), p.value_model, self.health,
                            limit=p.value_limit_um, slew=p.value_slew_um_s,
                            deadband=p.value_deadband_um, quantum=p.value_quantum_um,
                            max_dt_s=dt, initial=initial("value"), readback=readback,
                            state=model_state("value_model", p.value_sha256), fresh=fresh)
        self.slope = _Param(p.name("slope"), p.slope_model, self.health,
                            limit=p.slope_limit_um_m, slew=p.slope_slew_um_m_s,
                            deadband=p.slope_deadband_um_m, quantum=p.slope_quantum_um_m,
                            max_dt_s=dt, initial=initial("slope"), readback=readback,
                            state=model_state("slope_model", p.slope_sha256), fresh=fresh)
        self.params = (self.value, self.slope)
        self.gate = sorted(p.value_model.channels
                           | (p.slope_model.channels if p.slope_model is not None else set())
                           | ({p.position} if p.position is not None else set()))
        self._gate = frozenset(self.gate)
        #: the outputs' names, made once (the cycle uses them every cycle)
        self.names = p.names
        self._reference_name, self._offset_name = p.name("reference"), p.name("offset")
        #: an offset at the position: the last valid position (mm), and the offset
        #: and position of the last write the controller confirmed
        self._x: float | None = initial("position_mm")
        self._confirmed_at: tuple[float, float] | None = None
        if p.position is not None and self._x is not None \
                and (total := initial("offset_um")) is not None:
            self._confirmed_at = (total, self._x)
        self._offset_sent: tuple[float, float] | None = None
        #: the reference position was written and confirmed once (its read-back judged)
        self.reference_written = False
        self._planned: tuple[float | None, float | None, bool] = (None, None, False)
        self._models: tuple[float | None, float | None] = (None, None)
        self._valid = False
        #: this cycle's status word (int), cause and recorded state: functions of its
        #: `HealthView`, worked out once in `plan` for the axes word and the row
        self.status = 0
        self.cause = Cause.INPUTS_INVALID
        self._state = FaultState.INIT
        #: the controller confirmed the line compd wants last cycle (`AxisRow.in_force`)
        self.in_force = False

    @property
    def writing(self) -> bool:
        """This cycle's plan writes the axis's line."""
        return self._planned[2]

    def export_state(self) -> dict[str, Any]:
        out: dict[str, Any] = {"value": self.value.stage.confirmed_um,
                               "slope": self.slope.stage.confirmed_um}
        if self._confirmed_at is not None:
            out["offset_um"], out["position_mm"] = self._confirmed_at
        for key, param, sha in (("value_model", self.value, self.p.value_sha256),
                                ("slope_model", self.slope, self.p.slope_sha256)):
            m = param.models
            if m is not None and m.model_ready:
                out[key] = m.model.export_state()
                out[f"{key}_sha256"] = sha
        return out

    # -- plan ------------------------------------------------------------------------

    def judge(self, got: Mapping[str, float | None] | None, *, off: str | None,
              events: list[Event], position_mm: float | None = None) -> bool:
        """The read-back of this axis's parameters; whether it was read in full.
        `position_mm`: an axis at its position, the position read valid this cycle
        (None: none)."""
        was_off = self.health.controller(off, self.value.stage.current_um, events)
        # every name read (a value None: that one not read)
        full = got is not None and None not in map(got.get, self.names)
        seen = (self._as_parameters(got, position_mm) if self.p.position is not None
                else got)
        for param in self.params:
            v = seen.get(param.name) if seen is not None else None
            mine: list[Event] = []
            param.readback.judge(v, off=off, was_off=was_off, events=mine)
            if mine:
                events.extend(_tagged(mine, axis=self.p.axis, output=param.name))
        ref = got.get(self._reference_name) if got is not None else None
        if off is None and ref is not None and self.reference_written:
            tol = max(0.5 * self.p.reference_quantum_mm, FLOAT_TOLERANCE)
            if not (math.isfinite(ref) and abs(ref - self.p.reference_mm) <= tol):
                events.append(Event(EventName.READBACK_MISMATCH, {
                    "axis": self.p.axis, "output": self._reference_name,
                    "expected_um": self.p.reference_mm, "readback_um": finite_or_none(ref),
                    "action": "rewritten"}))
                self.health.foreign_seen()
        return full

    def _as_parameters(self, got: Mapping[str, float | None] | None,
                       position_mm: float | None) -> dict[str, float | None] | None:
        """The offset read back at the position, as the value and slope it stands for,
        so it is judged as the value's read-back: the offset compd last wrote (within
        half a count) is the value and slope confirmed; another (a second writer, a
        restarted controller at 0) is a value of the read-back less the slope's part
        at the position it was written at, so the value stage ramps from what the
        controller holds and the slope goes on. With no write confirmed yet (a start
        without a checkpoint of the offset, or with a checkpoint of the line's
        parameters alone) the controller applies its offset where the axis is now:
        the slope's part is taken at the position read this cycle (`position_mm`),
        else at the last valid one; with neither, nothing is judged (no value, no
        slope), and the axis, having no position to write at, holds until one is
        read."""
        if got is None:
            return None
        at = self._confirmed_at
        x = at[1] if at is not None else (position_mm if position_mm is not None
                                          else self._x)
        if x is None:
            return {self.value.name: None, self.slope.name: None}
        rb = got.get(self._offset_name)
        slope = self.slope.stage.confirmed_um
        value = self.value.stage.confirmed_um
        out: dict[str, float | None] = {self.slope.name: slope if slope is not None else 0.0}
        if rb is None or not math.isfinite(rb):
            out[self.value.name] = rb
            return out
        tol = max(0.5 * self.p.offset_quantum_um, FLOAT_TOLERANCE)
        if at is not None and value is not None and abs(rb - at[0]) <= tol:
            out[self.value.name] = value
            return out
        out[self.value.name] = rb - (slope or 0.0) * (x - self.p.reference_mm) / 1000.0
        return out

    def plan(self, now_s: float, dt: float, values: Mapping[str, float],
             validity: Mapping[str, str | None], answered: bool, *, hold: bool,
             events: list[Event], invalid: Collection[str] | None = None) -> HealthView:
        """Step the models, decide, move both stages; the axis's health view (its
        status word, cause and state kept for the axes word and the row).
        `invalid`: the channels invalid in `validity` (worked out once for every
        axis, `AxisBank.plan`; None: from `validity`)."""
        if invalid is None:
            invalid = _invalid_channels(validity)
        valid_inputs = answered and (not invalid or self._gate.isdisjoint(invalid))
        pos = self.p.position
        if answered and pos is not None and validity.get(pos) is None and not hold:
            # the axis's present position, valid and recent; under a hold (the
            # operator's, or the controller not permitting a change) the offset stays
            # as written, the position it was evaluated at with it
            self._x = values[pos]
        why: Cause | None = None
        model_invalid = model_range = False
        value_um = slope_um = None
        if valid_inputs:
            mine: list[Event] = []
            value_um = self.value.step(values, mine)
            slope_um = self.slope.step(values, mine)
            if value_um is None or slope_um is None:
                model_invalid = True
                why = Cause.MODEL_NON_FINITE
            else:
                in_range = (self.health.model_in_range(value_um, self.value.bound, mine)
                            and abs(slope_um) <= self.slope.bound)
                if not in_range:
                    model_range = True
                    why = Cause.MODEL_OUT_OF_RANGE
            if mine:
                events.extend(_tagged(mine, axis=self.p.axis))
        else:
            why = Cause.INPUTS_INVALID if answered else Cause.CONTROLLER_NOT_ANSWERING
        self._models = (value_um, slope_um)
        self._valid = why is None
        mine = []
        decision = self.health.decide(now_s, why, value_um if why is None else None, mine)
        if mine:
            events.extend(_tagged(mine, axis=self.p.axis))
        tracking = decision.state == FaultState.OK
        for param, model in ((self.value, value_um), (self.slope, slope_um)):
            stage = param.stage
            if self.health.controller_off is not None:
                stage.slewing = False
                continue
            if tracking and not hold and model is not None:
                target = model
            elif decision.target_um is not None and not tracking:
                target = 0.0  # ramping to zero (a fault, or the shutdown)
            else:
                target = stage.current_um
            stage.step(target, dt, deadband=tracking)
        held = self.value.stage.held or self.slope.stage.held
        slewing = self.value.stage.slewing or self.slope.stage.slewing
        self.health.foreign_settled(moving=slewing or held)
        view = HealthView(
            policy=decision.state, alarm=decision.alarm, write_stopped=self.health.write_stopped,
            write_fault=self.health.write_fault, held=held, foreign=self.health.foreign,
            slewing=slewing, model_invalid=model_invalid,
            model_range=model_range, controller_off=self.health.controller_off is not None,
            invalid=why, operator_hold=hold and tracking,
            at_limit=tracking and value_um is not None and slope_um is not None and (
                abs(value_um) > self.p.value_limit_um
                or abs(slope_um) > self.p.slope_limit_um_m))
        self.status = status_bits(view)
        self.cause = output_cause(view)
        self._state = recorded_state(view)
        return view

    def writes(self, full_readback: bool, readback: bool, events: list[Event]
               ) -> dict[str, float]:
        """This axis's writes (value, slope, reference), none when it cannot write."""
        h = self.health
        held = self.value.stage.held or self.slope.stage.held
        if h.write_stopped or held or h.controller_off is not None:
            self._planned = (None, None, False)
            return {}
        if readback and not full_readback:
            mine: list[Event] = []
            for param in self.params:
                param.readback.skip_write(mine)
            if mine:
                events.extend(_tagged(mine, axis=self.p.axis))
            self._planned = (None, None, False)
            return {}
        v, s = self.value.stage.current_um, self.slope.stage.current_um
        if self.p.position is not None:
            if self._x is None:  # no valid position yet: nothing to evaluate the line at
                self._planned = (None, None, False)
                return {}
            total = self.p.offset_at(v, s, self._x)
            self._offset_sent = (total, self._x)
            for param in self.params:
                param.readback.written()
            self._planned = (v, s, True)
            return {self._offset_name: total}
        for param in self.params:
            param.readback.written()
        self._planned = (v, s, True)
        if self.p.value_only:
            return {self.value.name: v}
        return {self.value.name: v, self.slope.name: s,
                self._reference_name: self.p.reference_mm}

    def row(self, confirmed: bool, failed: bool) -> AxisRow:
        """This cycle's row (after `plan` and `commit`)."""
        v_sent, s_sent, _ = self._planned
        cause = self.health.committed_cause(self.cause, offset_failed=failed)
        self.in_force = confirmed and v_sent is not None and cause.healthy
        return AxisRow(
            axis=self.p.axis, state=self._state, cause=cause,
            status=self.status,
            value=ParamRow(self._models[0], self.value.stage.current_um, v_sent,
                           self.value.stage.confirmed_um),
            slope=ParamRow(self._models[1], self.slope.stage.current_um, s_sent,
                           self.slope.stage.confirmed_um),
            reference_mm=self.p.reference_mm,
            in_force=self.in_force, inputs_valid=self._valid,
            position_mm=self._x if self.p.position is not None else None,
            offset_um=(self._offset_sent[0] if self._offset_sent is not None
                       and v_sent is not None else None))

    # -- commit ----------------------------------------------------------------------

    def commit(self, ok: bool, outputs: tuple[str, ...], permanent: bool, reason: str,
               later: list[Event]) -> tuple[bool, bool, list[Event]]:
        """How this cycle's writes went for this axis: (confirmed, failed, events).
        A failed write that named only other outputs confirms nothing here either
        (whether this axis's parameters arrived is unknown: the stages fall back to
        what the controller last confirmed, and the next read-back tells), but is
        no failure of this axis."""
        if not self._planned[2]:
            return False, False, []
        if ok:
            for param in self.params:
                param.stage.confirm()
            if self._offset_sent is not None:
                self._confirmed_at = self._offset_sent
            self.reference_written = True
            self.health.write_succeeded(later)
            return True, False, []
        for param in self.params:
            param.stage.revert()
        if outputs and not set(outputs) & set(self.names):
            return False, False, []
        failed = tuple(n for n in outputs if n in self.names)
        events = self.health.write_failed(
            failed, permanent=permanent, reason=reason, offset_failed=True,
            offset_name=failed[0] if failed else self.value.name,
            offset_um=self.value.stage.current_um)
        return False, True, _tagged(events, axis=self.p.axis)
