"""The sample cycle, sans I/O: samples and the time in; writes, events and the
record row out. No asyncio, no logging, no clock of its own, so hours of
machine time are tested in milliseconds with a fake clock.

One `Cycle.step(now_s, samples, readback_offset_um)`:

1. read-back: the controller's offset (controller units) against the value it
   last confirmed (`OutputStage.observe`); a value compd did not write (a
   second writer, a restarted controller that forgot it) is an alarm
   (READBACK_MISMATCH and ALARM until the output has ramped back to its
   target at the slew limit); beyond ±limit_um it is an alarm and no offset
   is written (OFFSET_HELD, state "held") until the controller's value is back
   within the limit, and then the output ramps from there;
2. validate every channel (`compd.core.validation`); the cycle is valid when every
   channel the live model reads is valid;
3. valid: initialise the model on the first valid sample if needed (restored
   state, or the steady state matching today's temperatures), then step it
   (and the shadow model) once; invalid: the filters are NOT stepped; a model
   output beyond MODEL_RANGE_FACTOR·limit_um makes the cycle invalid (a
   fault: hold, then ramp) with MODEL_RANGE and ALARM;
4. fault policy (`compd.core.faults`) picks the target; the output stage
   (`compd.core.output`) makes it safe;
   While the controller says it takes no offset (``controller_off``: machine
   off, E-stop; `[output] machine_on`/`estop`) the read-back is not judged,
   the output stage stands still and no offset is written (status
   CONTROLLER_OFF and HOLDING, state "hold"); the model keeps stepping. The
   first read-back once it is on again is what the controller holds (LinuxCNC
   zeroes its external offset at machine on): taken as it is, no alarm, and
   the output ramps from it at the slew limit;
5. writes: the offset (in controller units; omitted once the controller
   refused it permanently, and while read-back is configured but the read
   failed, since then the controller's state is unknown), the heartbeat
   (advanced only on a complete valid cycle) and the status word.

A cycle is COMPLETE (`offset_in_force`: the one definition, used by the
daemon's metrics, the checkpoint that `compd health --state-dir` reads, and
the recorder's ``complete`` column) only when the offset compd wants is the
offset in force: inputs valid and the model stepped, state "ok" (not held by
a foreign offset, no write fault, offset writes not stopped, no fault hold,
ramp or shutdown), and the controller confirmed this cycle's offset write
(`write_ok()`). `CycleResult.complete` is the narrower "inputs valid, model
stepped" that advances the heartbeat; `CycleResult.in_force` is the complete
cycle.

The shell reports each write's outcome with `write_ok()` / `write_failed()`;
WRITE_FAULT_AFTER offset writes failing in a row are a write fault (WRITE_FAULT
and ALARM, state "write_fault") until one succeeds. The record row keeps what
was sent (`attempted_um`) apart from what the controller confirmed
(`offset_um`: None once `write_failed()` said the offset did not arrive).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from compd.core.adaptation import AdaptationSettings, ProbeReading, ProbeStage
from compd.core.faults import Event, FaultPolicy, FaultState
from compd.core.output import OutputStage, Readback, Status
from compd.core.record import RecordRow
from compd.core.validation import ChannelLimits, Validator
from drivers.base import Sample
from models.compensation import CompensationModel
from models.errors import ModelError

if TYPE_CHECKING:
    from compd.config.loader import LoadedConfig

#: the heartbeat counts modulo this (fits INT, WORD, uint16, DINT, PMC word)
HEARTBEAT_MODULO = 32768

#: a model output beyond this many times limit_um is a fault (hold, then ramp,
#: alarm: MODEL_RANGE), not a value to clamp quietly: a model that far off is
#: broken (a thermal model near its limit may overshoot it, not by 5×)
MODEL_RANGE_FACTOR = 5.0

#: this many offset writes in a row failing (transient) are a write fault:
#: WRITE_FAULT and ALARM, state "write_fault", until a write succeeds
WRITE_FAULT_AFTER = 5


@dataclass(frozen=True)
class CycleParams:
    period_s: float
    hold_s: float
    limit_um: float
    slew_um_s: float
    channels: dict[str, ChannelLimits]
    deadband_um: float = 0.0
    sign: int = 1
    units_per_um: float = 1.0
    readback: bool = True
    #: a float offset address's (an integer one: half a count, `OutputStage`)
    readback_tolerance_um: float = 0.01
    #: the offset address's resolution in µm (integer types), 0 for floats
    offset_quantum_um: float = 0.0
    time_scale: float = 1.0
    offset_name: str = "offset"
    heartbeat_name: str | None = "heartbeat"
    status_name: str | None = "status"
    #: probe-assisted adaptation (`compd.core.adaptation`), None when off
    adaptation: AdaptationSettings | None = None


def params_from_config(cfg: LoadedConfig, *, dry_run: bool = False) -> CycleParams:
    raw = cfg.raw
    out = raw.output
    limits = {n: ChannelLimits(ch.range[0], ch.range[1], ch.max_rate_per_s, ch.stale_after_s,
                               ch.stuck_after_s, stuck_delta_k=ch.effective_stuck_delta_k,
                               temperature=ch.temperature)
              for n, ch in raw.channels.items()}
    return CycleParams(
        period_s=raw.machine.period_s, hold_s=raw.faults.hold_s, limit_um=out.limit_um,
        slew_um_s=out.slew_um_s, channels=limits, deadband_um=out.deadband_um, sign=out.sign,
        units_per_um=out.units_per_um, readback=out.readback and not dry_run,
        # float32 rounding; an integer address: half a count (OutputStage.observe)
        readback_tolerance_um=0.01,
        offset_quantum_um=cfg.offset_quantum_um,
        time_scale=raw.machine.time_scale,
        heartbeat_name="heartbeat" if "heartbeat" in cfg.outputs else None,
        status_name="status" if "status" in cfg.outputs else None,
        adaptation=cfg.adaptation)


def offset_in_force(*, valid: bool, state: FaultState, confirmed: bool) -> bool:
    """Whether a cycle is COMPLETE: the offset compd wants is the offset in force.

    `valid`: inputs valid and the model stepped; `state`: the state recorded for
    the cycle (`Cycle._state`: held, write_fault and stopped override the
    policy's); `confirmed`: the controller acknowledged this cycle's offset
    write. Only "ok" counts: a held, faulted, stopped, holding, ramping or
    shutting-down output is not what the model asks for, however busy the loop."""
    return valid and confirmed and state == FaultState.OK


@dataclass
class CycleResult:
    """What one cycle hands the shell: its `record` row (model output, state,
    channels, validity, contributions: read them there or through the
    properties) and what the shell does with it (writes, events, status)."""

    sequence: int
    #: output name -> value in controller units
    writes: dict[str, float]
    #: the output stage's value in µm (what was, or would be, written)
    offset_um: float
    shadow_um: float | None
    status: int
    heartbeat: int
    #: inputs valid and the model stepped (heartbeat advanced)
    complete: bool
    #: the recorder's row (wall_s: as passed to `step`, NaN when none was;
    #: the shell stamps the time of recording)
    record: RecordRow
    events: list[Event] = field(default_factory=list)
    #: a ramp-to-zero shutdown has reached zero (or cannot write any more)
    shutdown_done: bool = False

    @property
    def model_um(self) -> float | None:
        return self.record.model_um

    @property
    def state(self) -> FaultState:
        return FaultState(self.record.state)

    @property
    def in_force(self) -> bool:
        """A complete cycle (`offset_in_force`); known once `write_ok()` was called."""
        return self.record.complete


def _finite_or_none(x: float) -> float | None:
    return x if math.isfinite(x) else None


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
                 operator_hold: bool = False) -> None:
        self.params = params
        self.model = model
        self.shadow = shadow
        self.validator = Validator(params.channels, params.time_scale)
        self.faults = FaultPolicy(params.hold_s)
        self.output = OutputStage(
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
            self.output.confirm()
        self.sequence = sequence
        self.heartbeat = heartbeat % HEARTBEAT_MODULO
        self.gate = sorted(model.channels)
        self.write_stopped = False
        self.stopped_outputs: set[str] = set()
        self._references = dict(references) if references else None
        self._model_ready = False
        self._shadow_ready = False
        self._init_mode = "first_start" if references is None else "steady_state"
        self._last_now: float | None = None
        self._offset_pending = False
        self._invalid: dict[str, str] = {}
        self._mismatch_noted = False
        #: a foreign read-back was seen: alarm until the output tracks again
        self._foreign = False
        #: offset writes failed in a row; a write fault from WRITE_FAULT_AFTER on
        self.failed_writes = 0
        self.write_fault = False
        self._model_range = False
        self._result: CycleResult | None = None
        self._later: list[Event] = []
        #: why the controller takes no offset now ("machine_off", "estop"), None: it does
        self.controller_off: str | None = None
        self.probes: ProbeStage | None = None
        #: an operator's hold (`set_operator_hold`): the offset stays where it is
        self.operator_hold = operator_hold
        if params.adaptation is not None:
            try:
                self.probes = ProbeStage(params.adaptation, len(model.terms), adaptation_state)
            except (ValueError, KeyError, TypeError) as exc:
                self.probes = ProbeStage(params.adaptation, len(model.terms))
                self._later.append(Event("adaptation_state_refused", {"reason": str(exc)}))
        if model_state is not None:
            model.import_state(model_state)  # ModelError: the caller falls back
            self._model_ready = True
            self._init_mode = "restored"
            if shadow is not None and shadow_state is not None:
                try:
                    shadow.import_state(shadow_state)
                    self._shadow_ready = True
                except ModelError:
                    self._shadow_ready = False

    # -- construction from a checkpoint ---------------------------------------------

    @classmethod
    def from_state(cls, params: CycleParams, model: CompensationModel,
                   shadow: CompensationModel | None, state: Mapping[str, Any], *,
                   fresh: bool, same_model: bool = True) -> Cycle:
        """A cycle continuing `state` (an `export_state()` / checkpoint dict).
        Fresh: the filters resume where they were. Too old: only the references
        and the last written offset are kept; the filters restart at the steady
        state matching the first valid sample. The adaptation estimator resumes
        whenever the model is the same (`same_model`), fresh or not; another
        model clears it."""
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
        adapted = state.get("adaptation") if same_model else None
        return cls(params, model, shadow,
                   model_state=model_state if usable else None,
                   shadow_state=shadow_state if isinstance(shadow_state, Mapping) else None,
                   references=refs, offset_um=offset_um,
                   sequence=int(state.get("sequence", 0)),
                   heartbeat=int(state.get("heartbeat", 0)),
                   adaptation_state=adapted if isinstance(adapted, Mapping) else None,
                   operator_hold=state.get("operator_hold") is True)

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
        if self._model_ready:
            out["model"] = self.model.export_state()
            if self.shadow is not None and self._shadow_ready:
                out["shadow"] = self.shadow.export_state()
        else:
            out["model"] = None
            if self._references:
                out["references"] = dict(self._references)
        if self.probes is not None:
            out["adaptation"] = self.probes.export_state()
        if self.operator_hold:
            out["operator_hold"] = True
        return out

    def set_operator_hold(self, on: bool, who: str) -> Event | None:
        """An operator's hold (on) or its release (off). While held, a cycle
        that would track the model keeps the offset where it is (faults still
        hold and ramp as always); released, the output slews back to the model
        at the slew limit. Returns the event to log, None when nothing changed."""
        if on == self.operator_hold:
            return None
        self.operator_hold = on
        return Event("operator_hold" if on else "operator_release", {"by": who})

    # -- the cycle ------------------------------------------------------------------

    def begin_shutdown(self) -> None:
        """Ramp-to-zero shutdown: from now on the target is 0."""
        self.faults.shutting_down = True

    def step(self, now_s: float, samples: Mapping[str, Sample] | None,
             readback_offset_um: float | None = None, *,
             wall_s: float | None = None, probe: ProbeReading | None = None,
             controller_off: str | None = None) -> CycleResult:
        """One cycle at machine time `now_s`. `samples` None: the read failed.
        `readback_offset_um`: the controller's offset as read (controller units).
        `probe`: the measuring cycle's values as read (`compd.core.adaptation`).
        `controller_off`: why the controller takes no offset now (module, step 1)."""
        p = self.params
        self.sequence += 1
        events, self._later = self._later, []
        status = Status(0)
        dt = p.period_s if self._last_now is None else now_s - self._last_now

        was_off, self.controller_off = self.controller_off, controller_off
        off = controller_off is not None
        if off:
            status |= Status.CONTROLLER_OFF
            if was_off != controller_off:
                events.append(Event("controller_off", {
                    "reason": controller_off, "offset_um": self.output.current_um}))
        elif was_off is not None:
            rb = readback_offset_um
            rb_um = (self.output.from_controller(rb) if rb is not None and math.isfinite(rb)
                     else None)
            if rb_um is not None and abs(rb_um) <= self.output.limit_um:
                self.output.adopt(rb_um)  # what it holds now: ramp from there
            elif rb is not None:
                status |= self._readback(rb, events)
            events.append(Event("controller_on", {"was": was_off, "readback_um": rb_um}))
        elif readback_offset_um is not None:
            status |= self._readback(readback_offset_um, events)

        validity = self.validator.check(now_s, samples, wall_s)
        self._note_validity(validity, events)
        values = {n: (float(s.value) if (s := (samples or {}).get(n)) is not None else math.nan)
                  for n in p.channels}
        valid = all(validity.get(ch) is None for ch in self.gate)

        model_um: float | None = None
        shadow_um: float | None = None
        if valid:
            model_um = self._step_model(values, events)
            if model_um is None:
                status |= Status.MODEL_INVALID
                valid = False
            elif self._model_out_of_range(model_um, events):
                status |= Status.MODEL_RANGE | Status.ALARM
                valid = False
            elif self.shadow is not None:
                shadow_um = self._step_shadow(values, events)

        in_force = self.output.confirmed_um  # before this cycle's write
        correction = self._adapt(dt, probe, valid, model_um, in_force, events)
        if self.probes is not None and self.probes.model_worse:
            # the probes showed the compensation worse than none: a fault, like a model
            # out of range (hold, then ramp to zero per [faults]), latched
            status |= Status.MODEL_WORSE | Status.ALARM
            valid = False
        target_um = model_um + correction if model_um is not None else None
        decision = self.faults.decide(now_s, valid, target_um, events)
        target = self.output.current_um if decision.target_um is None else decision.target_um
        if self.operator_hold and decision.state == FaultState.OK:
            target = self.output.current_um
        if off:  # the output stands still while the controller takes no offset
            self.output.slewing = False
            offset_um = self.output.current_um
        else:
            offset_um = self.output.step(target, dt, deadband=decision.state == FaultState.OK)
        # only once the stage has moved: a step that raised before this (the shell then
        # steps again as a failed read) leaves the interval to that step, so a hold still ramps
        self._last_now = now_s

        if valid:
            self.heartbeat = (self.heartbeat + 1) % HEARTBEAT_MODULO
        status |= self._status_bits(decision.state, decision.alarm)
        if self._foreign:
            status |= Status.READBACK_MISMATCH | Status.ALARM
            # the alarm lasts until the output has ramped to its target
            self._foreign = self.output.slewing or self.output.held

        writes: dict[str, float] = {}
        self._offset_pending = False
        if not self.write_stopped and not self.output.held and not off:
            if p.readback and readback_offset_um is None:
                # the controller still holds what it last confirmed: start from there
                self.output.revert()
                offset_um = self.output.current_um
                if not self._mismatch_noted:
                    events.append(Event("offset_write_skipped", {"reason": "no_readback"}))
                    self._mismatch_noted = True
            else:
                self._mismatch_noted = False
                writes[p.offset_name] = self.output.to_controller(offset_um)
                self._offset_pending = True
        if p.heartbeat_name and p.heartbeat_name not in self.stopped_outputs:
            writes[p.heartbeat_name] = float(self.heartbeat)
        if p.status_name and p.status_name not in self.stopped_outputs:
            writes[p.status_name] = float(int(status))

        contributions = {t.name: c for t, c in zip(self.model.terms, self.model.contributions,
                                                    strict=True)} if valid else {}
        if shadow_um is not None:
            contributions["shadow_total"] = shadow_um
        if self.probes is not None and valid:
            contributions["adaptation"] = self.probes.correction_um
        record = RecordRow(
            seq=self.sequence, mono_s=now_s, wall_s=math.nan if wall_s is None else wall_s,
            offset_um=offset_um if p.offset_name in writes else None, model_um=model_um,
            state=self._state(decision.state), valid=valid,
            channels={n: _finite_or_none(v) for n, v in values.items()},
            validity=validity, contributions=contributions,
            attempted_um=offset_um if self._offset_pending else None,
            probe=self.probes.last if self.probes is not None else None)
        done = self.faults.shutting_down and (offset_um == 0.0 or self.write_stopped
                                              or self.output.held or off)
        self._result = CycleResult(
            sequence=self.sequence, writes=writes, offset_um=offset_um, shadow_um=shadow_um,
            status=int(status), heartbeat=self.heartbeat, complete=valid, record=record,
            events=events, shutdown_done=done)
        return self._result

    # -- write outcome ------------------------------------------------------------------

    def write_ok(self) -> None:
        """Every write of the last result reached the controller."""
        if self._offset_pending:
            self.output.confirm()
            r = self._result
            if r is not None and offset_in_force(valid=r.record.valid, state=r.state,
                                                 confirmed=True):
                r.record = dataclasses.replace(r.record, complete=True)
            if self.write_fault:
                self._later.append(Event("write_recovered", {"failed_writes":
                                                             self.failed_writes}))
            self.write_fault = False
            self.failed_writes = 0
        self._offset_pending = False

    def write_failed(self, output: str | None, *, permanent: bool,
                     reason: str = "") -> list[Event]:
        """A write of the last result failed. `output` names the refused
        output(s) when known (comma-separated for a combined write; any write
        that carried the offset stops the offset). Transient: retried next
        cycle from the confirmed value."""
        events: list[Event] = []
        offset_failed = self._offset_pending
        if offset_failed:
            self.output.revert()
            self._unconfirmed()
        self._offset_pending = False
        if not permanent:
            events.append(Event("write_failed", {"output": output, "reason": reason}))
            if offset_failed:
                self.failed_writes += 1
                if self.failed_writes >= WRITE_FAULT_AFTER and not self.write_fault:
                    self.write_fault = True
                    events.append(Event("write_fault", {
                        "failed_writes": self.failed_writes, "reason": reason,
                        "offset_um": self.output.current_um}))
            return events
        # a driver names every output of a refused combined write ("offset,heartbeat")
        names = {n.strip() for n in output.split(",")} if output else set()
        if not names or self.params.offset_name in names:
            if not self.write_stopped:
                self.write_stopped = True
                events.append(Event("offset_write_stopped", {
                    "output": output, "reason": reason,
                    "offset_um": self.output.current_um}))
            return events
        for name in sorted(names - self.stopped_outputs):
            self.stopped_outputs.add(name)
            events.append(Event("output_write_stopped", {"output": name, "reason": reason}))
        return events

    def _unconfirmed(self) -> None:
        """The last result's offset did not reach the controller: its record
        row keeps it as attempted only (`offset_um` is what was confirmed)."""
        r = self._result
        if r is not None and r.record.offset_um is not None:
            r.record = dataclasses.replace(r.record, offset_um=None)

    # -- internals ------------------------------------------------------------------------

    def _readback(self, value: float, events: list[Event]) -> Status:
        out = self.output
        rb_um = out.from_controller(value) if math.isfinite(value) else math.nan
        was_held, expected = out.held, out.confirmed_um
        seen = out.observe(rb_um, self.params.readback_tolerance_um)
        if seen is Readback.OUT_OF_RANGE:
            if not was_held:
                events.append(Event("readback_out_of_range", {
                    "expected_um": expected, "readback_um": _finite_or_none(rb_um),
                    "limit_um": out.limit_um, "action": "offset writes held"}))
            self._foreign = True
            return Status.READBACK_MISMATCH | Status.OFFSET_HELD | Status.ALARM
        if was_held:
            events.append(Event("readback_in_range", {
                "readback_um": rb_um, "action": "ramping from it"}))
            self._foreign = True
        if seen is Readback.ADOPTED:
            events.append(Event("readback_adopted", {"offset_um": out.current_um}))
        elif seen is Readback.FOREIGN:
            events.append(Event("readback_mismatch", {
                "expected_um": expected, "readback_um": rb_um, "action": "ramping from it"}))
            self._foreign = True
        return Status(0)

    def _state(self, state: FaultState) -> FaultState:
        """The state recorded and reported: the fault policy's, unless the
        offset is not reaching the controller."""
        if self.write_stopped:
            return FaultState.STOPPED
        if self.output.held:
            return FaultState.HELD
        if self.controller_off is not None and state == FaultState.OK:
            return FaultState.HOLD
        return FaultState.WRITE_FAULT if self.write_fault else state

    def _model_out_of_range(self, model_um: float, events: list[Event]) -> bool:
        """A model output beyond MODEL_RANGE_FACTOR·limit_um is a broken model,
        not a value to clamp: a fault (hold, then ramp) with an alarm."""
        bound = MODEL_RANGE_FACTOR * self.params.limit_um
        out = abs(model_um) > bound
        if out != self._model_range:
            self._model_range = out
            events.append(Event("model_out_of_range" if out else "model_in_range", {
                "model_um": model_um, "bound_um": bound}))
        return out

    def _note_validity(self, validity: Mapping[str, str | None], events: list[Event]) -> None:
        for name, reason in validity.items():
            before = self._invalid.get(name)
            if reason is not None and reason != before:
                self._invalid[name] = reason
                events.append(Event("channel_invalid", {"channel": name, "reason": reason}))
            elif reason is None and before is not None:
                del self._invalid[name]
                events.append(Event("channel_valid", {"channel": name, "was": before}))

    def _init_model(self, model: CompensationModel, values: Mapping[str, float]) -> float:
        refs = dict(self._references or {})
        for ch in model.reference_channels:
            refs.setdefault(ch, values[ch])
        model.set_references(refs)
        model.reset()
        return model.steady_state(values)

    def _step_model(self, values: Mapping[str, float], events: list[Event]) -> float | None:
        if not self._model_ready:
            y0 = self._init_model(self.model, values)
            self._references = dict(self.model.references)
            self._model_ready = True
            events.append(Event("model_initialised", {"mode": self._init_mode,
                                                      "steady_um": _finite_or_none(y0)}))
        y = self.model.step(values)
        if math.isfinite(y):
            return y
        events.append(Event("model_non_finite", {"model": self.model.name}))
        self._model_ready = False
        self._init_mode = "steady_state"
        return None

    def _step_shadow(self, values: Mapping[str, float], events: list[Event]) -> float | None:
        shadow = self.shadow
        if shadow is None:
            return None
        if not self._shadow_ready:
            self._init_model(shadow, values)
            self._shadow_ready = True
        y = shadow.step(values)
        if math.isfinite(y):
            return y
        events.append(Event("model_non_finite", {"model": shadow.name, "shadow": True}))
        self._shadow_ready = False
        return None

    def _adapt(self, dt: float, probe: ProbeReading | None, valid: bool,
               model_um: float | None, in_force_um: float | None,
               events: list[Event]) -> float:
        """The adaptation's correction to add to the model output (0 when off,
        in shadow mode, or while the cycle is not valid)."""
        if self.probes is None:
            return 0.0
        terms = self.model.contributions if valid else []
        correction = self.probes.step(dt, probe, complete=valid, model_um=model_um,
                                      terms_um=terms, offset_in_force_um=in_force_um,
                                      events=events)
        return correction if valid else 0.0

    def _status_bits(self, state: FaultState, alarm: bool) -> Status:
        s = Status(0)
        if state == FaultState.OK and not (self.write_stopped or self.output.held
                                           or self.write_fault):
            s |= Status.OK
        elif state in (FaultState.HOLD, FaultState.INIT):
            s |= Status.HOLDING
        elif state == FaultState.RAMP:
            s |= Status.RAMPING
        elif state == FaultState.SHUTDOWN:
            s |= Status.SHUTDOWN
        if alarm or self.write_stopped:
            s |= Status.ALARM
        if self.write_stopped:
            s |= Status.WRITE_STOPPED
        if self.output.held:
            s |= Status.OFFSET_HELD | Status.ALARM
        if self.write_fault:
            s |= Status.WRITE_FAULT | Status.ALARM
        if self.operator_hold:
            s |= Status.OPERATOR_HOLD
        if (self.operator_hold or self.controller_off is not None) and s & Status.OK:
            s = (s & ~Status.OK) | Status.HOLDING
        if self.output.slewing:
            s |= Status.SLEWING
        return s
