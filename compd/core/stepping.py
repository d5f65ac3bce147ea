"""Steps 2 and 3 of a cycle: the inputs validated, the models stepped (pure).

2. validate every channel (`compd.core.validation`); the cycle is valid when
   every channel the live model reads is valid (CHANNEL_INVALID and
   CHANNEL_VALID when a channel's verdict changes);
3. valid: initialise the model on the first valid sample if needed (restored
   state, or the steady state matching today's temperatures), then step it
   (and the shadow model) once; invalid: the filters are NOT stepped; a model
   output beyond MODEL_RANGE_FACTOR·limit_um makes the cycle invalid (a
   fault: hold, then ramp) with MODEL_RANGE and ALARM
   (`OutputHealth.model_in_range`). The fallback models
   (`compd.core.fallback`) step beside it on every answered cycle; when
   exactly one channel the model reads is invalid and a fallback covers it,
   that fallback's output is the model's from the first invalid sample on
   (cause DEGRADED, no hold, no alarm; FALLBACK_IN_FORCE), the output stage
   ramps the difference at the slew limit, and the main model takes over
   again, ramped the same way, when the channel is valid (FALLBACK_ENDED).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from compd.core.events import Event, EventName
from compd.core.health import Cause, OutputHealth
from compd.core.modelstep import ModelStepper
from compd.core.output import OutputStage
from compd.core.params import CycleParams
from compd.core.validation import Validator
from drivers.base import Sample

__all__ = ["MODEL_RANGE_FACTOR", "Inputs", "Stepped", "Stepping"]

#: a model output beyond this many times limit_um is a fault (hold, then ramp,
#: alarm: MODEL_RANGE), not a value to clamp quietly: a model that far off is
#: broken (a thermal model near its limit may overshoot it, not by 5×)
MODEL_RANGE_FACTOR = 5.0


@dataclass(frozen=True, slots=True)
class Inputs:
    """This cycle's channels: values (NaN when missing), why each is invalid."""

    values: dict[str, float]
    validity: dict[str, str | None]
    #: every channel the live model reads is valid
    valid: bool


@dataclass(frozen=True, slots=True)
class Stepped:
    """What the model made of the inputs."""

    model_um: float | None = None
    shadow_um: float | None = None
    #: inputs valid, the model stepped to a finite value within its range
    valid: bool = False
    model_invalid: bool = False
    model_range: bool = False
    #: the channel whose fallback model is in force this cycle (degraded), None: the main
    fallback_for: str | None = None

    def invalid(self, inputs: Inputs, answered: bool) -> Cause | None:
        """Why the model's output cannot be used this cycle (None: it can)."""
        if self.valid:
            return None
        if self.model_range:  # the live model's, or a fallback's in force
            return Cause.MODEL_OUT_OF_RANGE
        if not inputs.valid:
            return Cause.INPUTS_INVALID if answered else Cause.CONTROLLER_NOT_ANSWERING
        return Cause.MODEL_NON_FINITE if self.model_invalid else Cause.INPUTS_INVALID


class Stepping:
    """The validator, the models and what they remember between cycles."""

    def __init__(self, params: CycleParams, models: ModelStepper, gate: list[str],
                 health: OutputHealth) -> None:
        self.validator = Validator(params.channels, params.time_scale)
        self.models = models
        self.health = health
        self.channels = list(params.channels)
        #: the channels the live model reads: all valid, or the cycle is not
        self.gate = gate
        self.bound_um = MODEL_RANGE_FACTOR * params.limit_um
        #: why each channel is invalid, as last told (events on change)
        self._invalid: dict[str, str] = {}
        #: each channel the model reads at its last valid value (the live model steps
        #: on it while a fallback stands in for that channel)
        self._last_valid: dict[str, float] = {}
        #: the channel whose fallback is in force (events on change), None: the main model
        self.fallback_for: str | None = None

    def inputs(self, now_s: float, samples: Mapping[str, Sample] | None,
               wall_s: float | None, events: list[Event]) -> Inputs:
        validity = self.validator.check(now_s, samples, wall_s)
        self._note_validity(validity, events)
        got = samples or {}
        values = {n: (float(s.value) if (s := got.get(n)) is not None else math.nan)
                  for n in self.channels}
        return Inputs(values, validity, all(validity.get(ch) is None for ch in self.gate))

    def step(self, inputs: Inputs, events: list[Event], *, answered: bool) -> Stepped:
        if not answered:
            return Stepped()
        valid = {ch for ch in self.gate if inputs.validity.get(ch) is None}
        self.models.step_fallbacks(inputs.values, valid, events)
        if not inputs.valid:
            return self._degraded(inputs, valid, events)
        self._last_valid.update((ch, inputs.values[ch]) for ch in valid)
        model_um = self.models.step(inputs.values, events)
        if model_um is None:
            return Stepped(model_invalid=True)
        if not self.health.model_in_range(model_um, self.bound_um, events):
            return Stepped(model_um=model_um, model_range=True)
        shadow_um = self.models.step_shadow(inputs.values, events)
        return Stepped(model_um=model_um, shadow_um=shadow_um, valid=True)

    def _degraded(self, inputs: Inputs, valid: set[str], events: list[Event]) -> Stepped:
        """One channel the model reads is invalid and its fallback was stepped: the
        fallback's output is the model's this cycle (`compd.core.fallback`); else
        nothing stepped (the fault policy holds, then ramps). The live model keeps
        stepping with the lost channel at its last valid value, so every other term
        is current when the channel returns; its output is not used meanwhile."""
        bank = self.models.fallbacks
        lost = bank.in_force([ch for ch in self.gate if ch not in valid])
        fallback_um = bank.output_um(lost) if lost is not None else None
        if lost is None or fallback_um is None:
            return Stepped()
        self._last_valid.update((ch, inputs.values[ch]) for ch in valid)
        if self.models.model_ready and lost in self._last_valid:
            self.models.step({**inputs.values, lost: self._last_valid[lost]}, events)
        if not self.health.model_in_range(fallback_um, self.bound_um, events):
            return Stepped(model_um=fallback_um, model_range=True)
        return Stepped(model_um=fallback_um, valid=True, fallback_for=lost)

    def note_fallback(self, stepped: Stepped, output: OutputStage,
                      events: list[Event]) -> None:
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
                "offset_um": output.current_um, "slew_um_s": output.slew_um_s}))
        self.fallback_for = now

    def _note_validity(self, validity: Mapping[str, str | None], events: list[Event]) -> None:
        for name, reason in validity.items():
            before = self._invalid.get(name)
            if reason is not None and reason != before:
                self._invalid[name] = reason
                events.append(Event(EventName.CHANNEL_INVALID, {"channel": name, "reason": reason}))
            elif reason is None and before is not None:
                del self._invalid[name]
                events.append(Event(EventName.CHANNEL_VALID, {"channel": name, "was": before}))
