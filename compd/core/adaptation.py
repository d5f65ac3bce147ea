"""Probe-assisted adaptation in the cycle, sans I/O (`ProbeStage`).

A measuring cycle on the machine (a touch probe on a reference, a tool setter)
leaves two values in the controller: the measured Z deviation (µm) and a
counter that changes with every new measurement. The shell reads both every
cycle (`ProbeReading`); a probe is an event, recognised by the counter
changing, never by the value (the same value read twice is one measurement,
and two measurements may well agree).

Each cycle `ProbeStage.step`:

1. lets the estimator's time run (`models.adaptation.Adapter.advance`);
2. on a new probe: when the cycle is complete (inputs valid, model stepped)
   and the controller's offset is known, the measured displacement is the
   probe's value plus the offset in force (``measures = "residual"``: a probe
   on a compensating machine sees what the compensation left) or the value
   itself (``"displacement"``), and the estimator weighs it against the
   model's output (its gate refuses an outlier: a chip under the probe, a
   wrong tool); otherwise the probe is refused ("fault": never learnt from a
   sample the model could not use, "no_offset": the offset in force unknown);
3. when `reacquire_after` gate refusals in a row agreed in direction and the
   estimator re-acquired (a real change: `models.adaptation`), says so
   ("adaptation_reacquired"); when the estimator's score (`models.adaptation`: plain against adapted
   over the last `score_window` accepted probes) makes it stand down or take
   over again, says so ("adaptation_stood_down" with the two RMS errors,
   "adaptation_resumed");
4. guards against a model worse than none: a probe the estimator ACCEPTED
   (taken on a complete cycle with the offset in force known, and through
   its gate) tells what the error at the tool is with the compensation,
   d − o (d the measured displacement, o the offset in force), and what it
   would be without, d. When `guard_window` accepted probes in a row each
   show |d − o| > |d| + 2·probe_noise_um, the compensation makes the machine
   worse than none: "model_worse_than_none" is raised once (with how many
   accepted probes it decided on, and how many refused ones it left out)
   and latched (`model_worse`; the cycle sets MODEL_WORSE and ALARM and
   treats it as a fault: hold, then ramp to zero per [faults]), kept in the
   checkpoint, until another model is loaded (a restart or reload with a
   recalibrated model starts the estimator and the guard afresh). A probe
   the estimator refused (an outlier its gate threw out, a probe on an
   invalid cycle) is no evidence: it is counted (`refused`) and reported,
   never judged, so a broken or writable probe source cannot switch
   compensation off by sending outliers; a single wrong probe that passes
   the gate cannot trip it either: every probe of the window must agree.
   Refusals are not silent either: `DISAGREE_AFTER` gate refusals in a row
   mean the model or the probe source is wrong (a model so far off that
   re-acquisition cannot hold it, or a probe that reads nonsense): "probes_disagree"
   is raised once per such run (a warning for a person to look at both; the
   compensation is left as it is, since the probes cannot say which is wrong)
   and `gate_refusals` shows the run;
5. returns the correction to add to the model output. In ``mode = "apply"``
   the cycle adds it BEFORE the fault policy and the output stage, so clamp,
   slew and deadband apply to it as to the model: a jump of the estimate
   never becomes a jump at the tool. In ``"shadow"`` it is computed and
   recorded, never applied.

The first counter value seen with no counter remembered (a first start, or a
checkpoint without one) is a baseline, not a probe: it may be hours old.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

from compd.core.events import Event, EventName
from models.adaptation import AdaptationParams, Adapter, ProbeOutcome

__all__ = ["DISAGREE_AFTER", "AdaptationSettings", "ProbeReading", "ProbeStage"]

#: gate refusals in a row after which the probes and the model disagree (see 4.):
#: twice the default re-acquisition run, so a real change that re-acquisition
#: absorbs never raises it
DISAGREE_AFTER = 6


@dataclass(frozen=True)
class AdaptationSettings:
    """What `ProbeStage` does (``[adaptation]``, built by the config loader): the
    mode ("shadow": estimated and recorded; "apply": added to the model output),
    what the probe measures, the estimator's settings, the probes over which
    the guard "no model worse than none" judges the compensation (0: off), and
    what its verdict does ("fault": hold, then ramp to zero; "report": the
    event, status page and metric only). The guard judges the compensation in
    force, not the estimator's correction, so it acts in either mode."""

    mode: Literal["shadow", "apply"]
    measures: Literal["residual", "displacement"]
    params: AdaptationParams
    guard_window: int = 3
    guard_action: Literal["fault", "report"] = "fault"

    @property
    def guard_acts(self) -> bool:
        """A verdict of the guard is a fault (not only reported)."""
        return self.guard_action == "fault"


@dataclass(frozen=True)
class ProbeReading:
    """The probe's two controller values as read this cycle (NaN: not read)."""

    value_um: float
    counter: float


class ProbeStage:
    """The estimator, its probe counter and what it did last (see the module)."""

    def __init__(self, settings: AdaptationSettings, n_terms: int,
                 state: Mapping[str, Any] | None = None) -> None:
        self.settings = settings
        self.n_terms = n_terms
        self.adapter = Adapter(settings.params, n_terms)
        self.counter: float | None = None
        if state is not None:  # ValueError: the caller starts afresh
            self.adapter = Adapter.from_state(settings.params, n_terms, state["estimator"])
            counter = state.get("counter")
            self.counter = float(counter) if isinstance(counter, int | float) \
                and math.isfinite(counter) else None
        #: the correction the estimator proposes now (µm); applied only in "apply"
        self.correction_um = 0.0
        #: the last probe's outcome (recorded with its cycle), None when none came
        self.last: dict[str, Any] | None = None
        #: per accepted probe judged (the last guard_window): did the compensation
        #: make it worse?
        self.guard: list[bool] = []
        #: the guard tripped (latched): the compensation made the machine worse than none
        self.model_worse = False
        #: probes the estimator accepted / refused since start (refused: no evidence)
        self.accepted = 0
        self.refused = 0
        #: probes refused since the current run of worse accepted probes began
        #: (left out of the guard's judgement; reported when it trips)
        self.refused_in_window = 0
        #: gate refusals in a row (any accepted probe ends the run)
        self.gate_refusals = 0
        if state is not None:
            guard = state.get("guard")
            # a guard list without "guard_accepted_only" may hold refused probes' judgements
            if isinstance(guard, list) and all(isinstance(g, bool) for g in guard) \
                    and state.get("guard_accepted_only") is True:
                self.guard = guard[-max(1, settings.guard_window):]
            self.model_worse = state.get("model_worse") is True

    @property
    def applies(self) -> bool:
        return self.settings.mode == "apply"

    def step(self, dt_s: float, reading: ProbeReading | None, *, complete: bool,
             model_um: float | None, terms_um: Sequence[float],
             offset_in_force_um: float | None, events: list[Event]) -> float:
        """One cycle (see the module); returns the correction to apply (0 in shadow)."""
        if dt_s > 0.0 and math.isfinite(dt_s):
            self.adapter.advance(dt_s)
        self.last = None
        if reading is not None and math.isfinite(reading.counter) \
                and reading.counter != self.counter:
            first = self.counter is None
            self.counter = reading.counter
            if not first:
                self._probe(reading, complete, model_um, terms_um, offset_in_force_um, events)
        if complete and len(terms_um) == self.n_terms:
            self.correction_um = self.adapter.correction_um(terms_um)
        return self.correction_um if self.applies else 0.0

    def _probe(self, reading: ProbeReading, complete: bool, model_um: float | None,
               terms_um: Sequence[float], offset_um: float | None,
               events: list[Event]) -> None:
        value = reading.value_um
        model = model_um if model_um is not None else math.nan
        terms = terms_um if len(terms_um) == self.n_terms else [math.nan] * self.n_terms
        residual = self.settings.measures == "residual"
        measured = value + (offset_um if offset_um is not None else math.nan) \
            if residual else value
        if not complete or model_um is None:
            out = self.adapter.refuse("fault", measured, model, terms)
        elif residual and offset_um is None:
            out = self.adapter.refuse("no_offset", measured, model, terms)
        elif not math.isfinite(value):
            out = self.adapter.refuse("fault", measured, model, terms)
        else:
            was_down = self.adapter.standing_down
            out = self.adapter.update(measured, model, terms)
            if out.reacquired:
                events.append(Event(EventName.ADAPTATION_REACQUIRED, {
                    "innovation_um": round(out.innovation_um, 6),
                    "refusals": int(self.settings.params.reacquire_after),
                    "estimated_bias_um": round(out.estimated_bias_um, 6),
                    "bias_um": round(out.bias_um, 6),
                    "reacquisitions": self.adapter.reacquisitions}))
            if out.standing_down != was_down:
                plain, adapted = self.adapter.score_um
                events.append(Event(
                    EventName.ADAPTATION_STOOD_DOWN if out.standing_down
                    else EventName.ADAPTATION_RESUMED,
                    {"plain_rms_um": round(plain, 6), "adapted_rms_um": round(adapted, 6),
                     "probes": int(self.settings.params.score_window),
                     "stand_downs": self.adapter.stand_downs}))
        if out.accepted:
            self.accepted += 1
            self.gate_refusals = 0
            if offset_um is not None and math.isfinite(measured):
                self._guard(measured, offset_um, events)
        else:
            self.refused += 1
            self.refused_in_window += 1
            if out.reason == "gate":
                self.gate_refusals += 1
                if self.gate_refusals == DISAGREE_AFTER:
                    events.append(Event(EventName.PROBES_DISAGREE, {
                        "gate_refusals": self.gate_refusals,
                        "innovation_um": round(out.innovation_um, 6)
                        if math.isfinite(out.innovation_um) else None,
                        "action": "check the model and the probe; compensation unchanged"}))
        self.last = self._describe(reading, measured, model, out)
        fields = {k: v for k, v in self.last.items() if k != "accepted"}
        events.append(Event(EventName.PROBE_ACCEPTED if out.accepted
                            else EventName.PROBE_REFUSED, fields))

    def _guard(self, displacement_um: float, offset_um: float, events: list[Event]) -> None:
        """Judge one accepted probe: the error with the compensation against
        without (see 4.)."""
        window = self.settings.guard_window
        if window <= 0 or self.model_worse:
            return
        with_um, without_um = displacement_um - offset_um, displacement_um
        margin = 2.0 * self.settings.params.probe_noise_um
        worse = abs(with_um) > abs(without_um) + margin
        if not (worse and self.guard and self.guard[-1]):
            # the refused probes counted are those among the current run of evidence
            self.refused_in_window = 0
        self.guard.append(worse)
        del self.guard[:-window]
        if len(self.guard) == window and all(self.guard):
            self.model_worse = True
            events.append(Event(EventName.MODEL_WORSE_THAN_NONE, {
                "accepted_probes": window, "refused_probes": self.refused_in_window,
                "error_with_um": round(with_um, 6),
                "error_without_um": round(without_um, 6), "margin_um": round(margin, 6),
                "action": "fault: hold, then ramp to zero; recalibrate"
                if self.settings.guard_acts
                else "reported only (guard_action = report); recalibrate"}))

    @property
    def guard_worse(self) -> int:
        """Accepted probes in a row (the latest) that showed the compensation worse."""
        n = 0
        for worse in reversed(self.guard):
            if not worse:
                break
            n += 1
        return n

    def _describe(self, reading: ProbeReading, measured: float, model: float,
                  out: ProbeOutcome) -> dict[str, Any]:
        def num(x: float) -> float | None:
            return round(x, 6) if math.isfinite(x) else None

        return {"counter": reading.counter, "value_um": num(reading.value_um),
                "measured_um": num(measured), "model_um": num(model),
                "innovation_um": num(out.innovation_um),
                "innovation_sigma_um": num(out.innovation_sigma_um),
                "accepted": out.accepted, "reason": out.reason,
                "bias_um": num(out.bias_um), "bias_sigma_um": num(out.bias_sigma_um),
                "standing_down": out.standing_down,
                "mode": self.settings.mode}

    def export_state(self) -> dict[str, Any]:
        return {"estimator": self.adapter.export_state(), "counter": self.counter,
                "guard": list(self.guard), "guard_accepted_only": True,
                "model_worse": self.model_worse}
