"""The fallback models as the cycle steps them (pure): one model per input
channel whose loss it covers (`CompensationModel.fallbacks`, the model file's
``[[fallback]]``), each on the remaining channels.

Every fallback is stepped on every cycle whose read answered and whose
channels (all but the one it stands in for) are valid, whether or not it is
in force: when its channel fails, its state is the one it would have had all
along, so the switch is warm, never a cold start. A fallback starts at the
steady state of the first such sample, relative to the main model's
reference state (the same `steady` the main model starts with), or resumes
a fresh checkpoint's state.

`in_force(invalid)` picks the fallback for this cycle: exactly one channel the
main model reads is invalid, there is a fallback for it, and that fallback
was stepped this cycle (its own channels valid) to a finite value. Two or
more channels invalid, no fallback for the one, or a fallback that cannot be
stepped: None, and the fault policy holds, then ramps, as without fallbacks.

A re-zero (`rezero`) takes each fallback's present prediction as its own zero
alongside the main model's, so a fallback that comes into force later is
relative to the same touch-off.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Collection, Mapping
from typing import Any

from compd.core.events import Event, EventName
from models.compensation import CompensationModel
from models.errors import ModelError

#: how a fallback is started at the steady state of a sample: (model, values) -> output
Steady = Callable[[CompensationModel, Mapping[str, float]], float]


class FallbackBank:
    """The fallbacks by the channel each covers; their readiness, zeros, last outputs."""

    def __init__(self, fallbacks: Mapping[str, CompensationModel], *,
                 states: Mapping[str, Any] | None = None,
                 zeros: Mapping[str, Any] | None = None) -> None:
        self.models = dict(fallbacks)
        self.ready = dict.fromkeys(self.models, False)
        #: each fallback's prediction of this cycle (raw, before its zero), None: not stepped
        self.raw_um: dict[str, float | None] = dict.fromkeys(self.models)
        self.zero_um = dict.fromkeys(self.models, 0.0)
        for lost, z in (zeros or {}).items():
            if lost in self.zero_um and isinstance(z, int | float) and math.isfinite(z):
                self.zero_um[lost] = float(z)
        for lost, state in (states or {}).items():
            fb = self.models.get(lost)
            if fb is None or not isinstance(state, Mapping):
                continue
            try:
                fb.import_state(state)
            except (ModelError, TypeError, ValueError, KeyError):
                continue  # started at the steady state of its first sample instead
            self.ready[lost] = True

    def __bool__(self) -> bool:
        return bool(self.models)

    def step(self, values: Mapping[str, float], valid: Collection[str], steady: Steady,
             events: list[Event]) -> None:
        """Step every fallback whose channels are all in `valid` (others keep their
        state and have no prediction this cycle)."""
        for lost, fb in self.models.items():
            self.raw_um[lost] = None
            if not fb.channels <= set(valid) or lost in fb.channels:
                continue
            if not self.ready[lost]:
                steady(fb, values)
                self.ready[lost] = True
            y = fb.step(values)
            if math.isfinite(y):
                self.raw_um[lost] = y
            else:
                events.append(Event(EventName.MODEL_NON_FINITE,
                                    {"model": fb.name, "fallback_for": lost}))
                self.ready[lost] = False

    def in_force(self, invalid: Collection[str]) -> str | None:
        """The channel whose fallback takes over this cycle (module docstring), or None."""
        if len(invalid) != 1:
            return None
        (lost,) = invalid
        return lost if self.raw_um.get(lost) is not None else None

    def output_um(self, lost: str) -> float | None:
        """The fallback's prediction this cycle less its zero (None: not stepped)."""
        raw = self.raw_um.get(lost)
        return None if raw is None else raw - self.zero_um[lost]

    def rezero(self) -> None:
        for lost, raw in self.raw_um.items():
            if raw is not None:
                self.zero_um[lost] = raw

    def drop_zero(self) -> None:
        self.zero_um = dict.fromkeys(self.models, 0.0)

    def export_state(self) -> dict[str, Any]:
        """The started fallbacks' states, by the channel each covers."""
        return {lost: fb.export_state() for lost, fb in self.models.items() if self.ready[lost]}
