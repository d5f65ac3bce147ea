"""The live model and its shadow as the cycle steps them (pure): first-valid-
sample initialisation (restored state, or the steady state matching today's
temperatures), one step per valid cycle, a non-finite output re-initialises
at the steady state, and the state a checkpoint keeps.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from compd.core.events import Event, EventName
from models.compensation import CompensationModel
from models.errors import ModelError


def finite_or_none(x: float) -> float | None:
    return x if math.isfinite(x) else None


class ModelStepper:
    """The model, its shadow (None without one) and whether each is initialised."""

    def __init__(self, model: CompensationModel, shadow: CompensationModel | None, *,
                 model_state: Mapping[str, Any] | None = None,
                 shadow_state: Mapping[str, Any] | None = None,
                 references: Mapping[str, float] | None = None) -> None:
        self.model = model
        self.shadow = shadow
        self.references = dict(references) if references else None
        self.model_ready = False
        self.shadow_ready = False
        self.init_mode = "first_start" if references is None else "steady_state"
        if model_state is not None:
            model.import_state(model_state)  # ModelError: the caller falls back
            self.model_ready = True
            self.init_mode = "restored"
            if shadow is not None and shadow_state is not None:
                try:
                    shadow.import_state(shadow_state)
                    self.shadow_ready = True
                except ModelError:
                    self.shadow_ready = False

    def export_state(self) -> dict[str, Any]:
        """The model's part of the checkpoint (`Cycle.export_state`)."""
        out: dict[str, Any] = {}
        if self.model_ready:
            out["model"] = self.model.export_state()
            if self.shadow is not None and self.shadow_ready:
                out["shadow"] = self.shadow.export_state()
        else:
            out["model"] = None
            if self.references:
                out["references"] = dict(self.references)
        return out

    def contributions(self) -> dict[str, float]:
        """Each term's part of the last step, by term name."""
        return {t.name: c for t, c in zip(self.model.terms, self.model.contributions,
                                          strict=True)}

    def _init(self, model: CompensationModel, values: Mapping[str, float]) -> float:
        refs = dict(self.references or {})
        for ch in model.reference_channels:
            refs.setdefault(ch, values[ch])
        model.set_references(refs)
        model.reset()
        return model.steady_state(values)

    def step(self, values: Mapping[str, float], events: list[Event]) -> float | None:
        """One step of the live model; None when its output was not finite."""
        if not self.model_ready:
            y0 = self._init(self.model, values)
            self.references = dict(self.model.references)
            self.model_ready = True
            events.append(Event(EventName.MODEL_INITIALISED, {"mode": self.init_mode,
                                                      "steady_um": finite_or_none(y0)}))
        y = self.model.step(values)
        if math.isfinite(y):
            return y
        events.append(Event(EventName.MODEL_NON_FINITE, {"model": self.model.name}))
        self.model_ready = False
        self.init_mode = "steady_state"
        return None

    def step_shadow(self, values: Mapping[str, float], events: list[Event]) -> float | None:
        """One step of the shadow model; None without one or when not finite."""
        shadow = self.shadow
        if shadow is None:
            return None
        if not self.shadow_ready:
            self._init(shadow, values)
            self.shadow_ready = True
        y = shadow.step(values)
        if math.isfinite(y):
            return y
        events.append(Event(EventName.MODEL_NON_FINITE, {"model": shadow.name, "shadow": True}))
        self.shadow_ready = False
        return None
