"""The live model and its shadow as the cycle steps them (pure): the
reference state, first-valid-sample initialisation, one step per valid cycle,
a non-finite output re-initialised at the steady state, the re-zero, and the
state a checkpoint keeps.

The reference state (the temperatures at which the model's growth is zero)
is explicit when it can be: the model's calibration reference (the model
file's ``[reference]``, or ``[model] reference`` in the config), else the
one a checkpoint recorded, else (a first start knowing neither) the
temperatures of the first valid sample, which is said (``reference``
``first_sample`` in ``model_initialised``): a machine already warm then
predicts nothing of the heat it holds.

Initialisation on the first valid sample, in this order:

- ``restored``: a fresh checkpoint's filter state (the daemon was off a
  moment);
- ``advanced``: a checkpoint too old to resume, of the same model and
  reference: its filter state stepped on over the time since it was saved
  with today's inputs held (`MAX_ADVANCE_STEPS` steps at most; a longer gap is
  several time constants of any thermal model, where the steady state is the
  same thing);
- ``steady_state``: every term at the steady state of today's inputs relative
  to the reference: a warm machine predicts its growth from the first cycle;
- ``first_start``: neither a reference nor a checkpoint: the reference is
  the first sample, the state at rest (predicts 0).

Re-zero (`rezero`): the present prediction becomes the new zero: every
later output is the prediction minus it (the growth since the touch-off,
exact for a linear model: the filters keep stepping untouched). The zero is
kept in the checkpoint (restored with the same model, whatever the
checkpoint's age) and dropped with another model (`drop_zero`).

The fallback models (`compd.core.fallback`) are stepped here too, beside the
live model, and share its reference state, re-zero and checkpoint.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from compd.core.events import Event, EventName
from compd.core.fallback import FallbackBank
from models.compensation import CompensationModel
from models.errors import ModelError

#: the most steps a too-old checkpoint's state is advanced by at start (at 1 s per
#: sample, 12 h; any gap at 60 s): beyond, the steady state of today's inputs
MAX_ADVANCE_STEPS = 43_200


def finite_or_none(x: float) -> float | None:
    return x if math.isfinite(x) else None


class ModelStepper:
    """The model, its shadow (None without one) and whether each is initialised.

    The models given are descriptions (a config's, or a caller's): the stepper
    steps copies of its own (`CompensationModel.fresh`), so a config, and the
    model in it, can be shared and reused by another cycle (a reload, a
    restart, a replay) without carrying this one's filter state."""

    def __init__(self, model: CompensationModel, shadow: CompensationModel | None, *,
                 model_state: Mapping[str, Any] | None = None,
                 shadow_state: Mapping[str, Any] | None = None,
                 references: Mapping[str, float] | None = None,
                 stale_state: Mapping[str, Any] | None = None,
                 stale_age_s: float | None = None,
                 zero: Mapping[str, Any] | None = None,
                 fallback_states: Mapping[str, Any] | None = None) -> None:
        model = model.fresh()
        self.model = model
        self.shadow = shadow.fresh() if shadow is not None else None
        shadow = self.shadow
        explicit = dict(model.calibration_reference)
        #: where the reference state came from: calibration, checkpoint, first_sample
        self.reference_source = "calibration" if explicit else (
            "checkpoint" if references else "first_sample")
        self.references = explicit or (dict(references) if references else None)
        self.model_ready = False
        self.shadow_ready = False
        self.init_mode = "first_start" if self.references is None else "steady_state"
        self._stale = dict(stale_state) if stale_state is not None else None
        self._stale_age_s = stale_age_s
        #: the raw prediction of the last step (before the zero), None before one
        self.last_raw_um: float | None = None
        self.last_shadow_raw_um: float | None = None
        self.zero_um = 0.0
        self.shadow_zero_um = 0.0
        #: who re-zeroed, and when (wall seconds), None: never
        self.zero_by: str | None = None
        self.zero_wall_s: float | None = None
        fallback_zeros = zero.get("fallback_um") if zero is not None else None
        self.fallbacks = FallbackBank(
            model.fallbacks, states=fallback_states if model_state is not None else None,
            zeros=fallback_zeros if isinstance(fallback_zeros, Mapping) else None)
        if zero is not None:
            self._import_zero(zero)
        if model_state is not None:
            model.import_state(model_state)  # ModelError: the caller falls back
            self.model_ready = True
            self.init_mode = "restored"
            self.reference_source = "checkpoint"
            self.references = dict(model.references)
            if shadow is not None and shadow_state is not None:
                try:
                    shadow.import_state(shadow_state)
                    self.shadow_ready = True
                except ModelError:
                    self.shadow_ready = False

    def _import_zero(self, zero: Mapping[str, Any]) -> None:
        um, shadow_um = zero.get("um"), zero.get("shadow_um", 0.0)
        if not (isinstance(um, int | float) and math.isfinite(um)
                and isinstance(shadow_um, int | float) and math.isfinite(shadow_um)):
            raise ValueError(f"checkpoint zero: not a number ({zero!r})")
        self.zero_um, self.shadow_zero_um = float(um), float(shadow_um)
        by, wall = zero.get("by"), zero.get("wall_s")
        self.zero_by = by if isinstance(by, str) else None
        self.zero_wall_s = float(wall) if isinstance(wall, int | float) else None

    def export_state(self) -> dict[str, Any]:
        """The model's part of the checkpoint (`Cycle.export_state`)."""
        out: dict[str, Any] = {}
        if self.model_ready:
            out["model"] = self.model.export_state()
            if self.shadow is not None and self.shadow_ready:
                out["shadow"] = self.shadow.export_state()
            if self.fallbacks:
                out["fallbacks"] = self.fallbacks.export_state()
        else:
            out["model"] = None
            if self.references:
                out["references"] = dict(self.references)
        if self.zero_by is not None:
            out["zero"] = {"um": self.zero_um, "shadow_um": self.shadow_zero_um,
                           "by": self.zero_by, "wall_s": self.zero_wall_s}
            if self.fallbacks:
                out["zero"]["fallback_um"] = dict(self.fallbacks.zero_um)
        return out

    def contributions(self) -> dict[str, float]:
        """Each term's part of the last step, by term name."""
        return {t.name: c for t, c in zip(self.model.terms, self.model.contributions,
                                          strict=True)}

    # -- initialisation ---------------------------------------------------------------

    def _steady(self, model: CompensationModel, values: Mapping[str, float]) -> float:
        refs = dict(self.references or {})
        for ch in model.reference_channels:
            refs.setdefault(ch, values[ch])
        model.set_references(refs)
        model.reset()
        return model.steady_state(values)

    def _advance(self, values: Mapping[str, float]) -> dict[str, Any] | None:
        """A too-old checkpoint's state stepped over the time since it with today's
        inputs held (module docstring); None when it cannot be (then steady state)."""
        stale, age = self._stale, self._stale_age_s
        self._stale = None
        if stale is None or age is None or not math.isfinite(age) or age < 0.0:
            return None
        steps = round(age / self.model.period_s)
        if steps > MAX_ADVANCE_STEPS:
            return {"advanced": False, "reason": "gap beyond the advance horizon",
                    "age_s": age, "max_steps": MAX_ADVANCE_STEPS}
        refs = stale.get("references")
        if self.references is not None and refs != self.references:
            return {"advanced": False, "reason": "another reference state", "age_s": age}
        try:
            self.model.import_state(stale)
        except (ModelError, TypeError, ValueError, KeyError) as exc:
            return {"advanced": False, "reason": str(exc), "age_s": age}
        step = self.model.step
        for _ in range(steps):
            step(values)
        return {"advanced": True, "age_s": age, "steps": steps}

    def _init_model(self, values: Mapping[str, float], events: list[Event]) -> None:
        fields: dict[str, Any] = {}
        advanced = self._advance(values)
        if advanced is not None and advanced.pop("advanced"):
            self.init_mode = "advanced"
            fields.update(advanced)
        else:
            if advanced is not None:
                fields["not_advanced"] = advanced
            y0 = self._steady(self.model, values)
            fields["steady_um"] = finite_or_none(y0 - self.zero_um)
        self.references = dict(self.model.references)
        self.model_ready = True
        events.append(Event(EventName.MODEL_INITIALISED, {
            "mode": self.init_mode, "reference": self.reference_source,
            "references": dict(self.references), **fields}))

    # -- stepping ---------------------------------------------------------------------

    def step(self, values: Mapping[str, float], events: list[Event]) -> float | None:
        """One step of the live model, less the zero; None when not finite."""
        if not self.model_ready:
            self._init_model(values, events)
        y = self.model.step(values)
        if math.isfinite(y):
            self.last_raw_um = y
            return y - self.zero_um
        events.append(Event(EventName.MODEL_NON_FINITE, {"model": self.model.name}))
        self.model_ready = False
        self.last_raw_um = None
        self.init_mode = "steady_state"
        return None

    def step_fallbacks(self, values: Mapping[str, float], valid: set[str],
                       events: list[Event]) -> None:
        """One step of every fallback whose channels are in `valid` (`FallbackBank.step`),
        each started at the steady state relative to the live model's reference state."""
        if self.fallbacks:
            self.fallbacks.step(values, valid, self._steady, events)

    def step_shadow(self, values: Mapping[str, float], events: list[Event]) -> float | None:
        """One step of the shadow model, less its zero; None without one or when not finite."""
        shadow = self.shadow
        if shadow is None:
            return None
        if not self.shadow_ready:
            self._steady(shadow, values)
            self.shadow_ready = True
        y = shadow.step(values)
        if math.isfinite(y):
            self.last_shadow_raw_um = y
            return y - self.shadow_zero_um
        events.append(Event(EventName.MODEL_NON_FINITE, {"model": shadow.name, "shadow": True}))
        self.shadow_ready = False
        self.last_shadow_raw_um = None
        return None

    # -- re-zero ----------------------------------------------------------------------

    def rezero(self, who: str, wall_s: float | None) -> Event:
        """Take the present prediction as the new zero (REZERO), or say why not
        (REZERO_REFUSED: no prediction yet)."""
        raw = self.last_raw_um
        if raw is None or not self.model_ready:
            return Event(EventName.REZERO_REFUSED, {
                "by": who, "reason": "no prediction yet (no valid cycle since start)"})
        was = self.zero_um
        self.zero_um = raw
        if self.last_shadow_raw_um is not None:
            self.shadow_zero_um = self.last_shadow_raw_um
        self.fallbacks.rezero()
        self.zero_by = who
        self.zero_wall_s = wall_s
        return Event(EventName.REZERO, {"by": who, "zero_um": raw, "was_zero_um": was,
                                        "prediction_was_um": raw - was})

    def drop_zero(self, reason: str) -> Event | None:
        """Forget the re-zero (another model: its zero is the other model's number)."""
        if self.zero_by is None:
            return None
        event = Event(EventName.REZERO_DROPPED, {"reason": reason, "zero_um": self.zero_um,
                                                 "by": self.zero_by})
        self.zero_um = self.shadow_zero_um = 0.0
        self.fallbacks.drop_zero()
        self.zero_by = self.zero_wall_s = None
        return event
