"""A compensation model: a sum of terms (docs/models.md §3).

Each term takes a signed combination of named channels relative to their
reference values (e.g. ``bearing - column``), passes it through one filter
(a `TransferFunction`, `GreyBox` or `Mbotv`), and multiplies by a gain that
is either fixed or the current value of a named channel (the lathe's
clamping-diameter gain g)::

    δZ(k) = Σ_terms gain · filter( Σ_ch c_ch · (x_ch(k) - ref_ch) )

Worked number (SP2 per-spindle, eq. 2): 1 K on the bearing and 0 K on the
ambient give 16.0005 µm on the first sample.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from models.errors import ModelError
from models.greybox import GreyBox
from models.mbotv import Mbotv
from models.tf import TransferFunction

Dynamics = TransferFunction | GreyBox | Mbotv


@dataclass
class Term:
    """One additive term. `inputs` maps channel -> coefficient."""

    name: str
    inputs: dict[str, float]
    dynamics: Dynamics
    gain: float = 1.0
    gain_channel: str | None = None
    #: subtract each channel's reference value (temperatures); False for power/speed inputs
    relative: bool = True
    #: grey-box u2 switch channel (> 0.5 = moving)
    switch_channel: str | None = None
    _refs: dict[str, float] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        if not self.name:
            raise ModelError("term: every term needs a name")
        if not self.inputs:
            raise ModelError(f"{self.name}.inputs: a term needs at least one input channel")
        for ch, c in self.inputs.items():
            if not isinstance(ch, str) or not ch:
                raise ModelError(f"{self.name}.inputs: channel names must be non-empty strings")
            if isinstance(c, bool) or not isinstance(c, int | float) or not math.isfinite(c):
                raise ModelError(f"{self.name}.inputs.{ch}: coefficient must be a finite "
                                 f"number, got {c!r}")
        if isinstance(self.gain, bool) or not math.isfinite(self.gain):
            raise ModelError(f"{self.name}.gain: must be a finite number, got {self.gain!r}")
        if self.switch_channel is not None and not isinstance(self.dynamics, GreyBox):
            raise ModelError(f"{self.name}.switch_channel: only a grey-box term has a u2 switch")
        self._lin: tuple[tuple[str, float, float], ...] = ()
        self._rebuild()

    def _rebuild(self) -> None:
        self._lin = tuple((ch, float(c), self._refs.get(ch, 0.0) if self.relative else 0.0)
                          for ch, c in self.inputs.items())

    @property
    def channels(self) -> set[str]:
        out = set(self.inputs)
        if self.gain_channel:
            out.add(self.gain_channel)
        if self.switch_channel:
            out.add(self.switch_channel)
        return out

    def input_value(self, sample: Mapping[str, float]) -> float:
        u = 0.0
        for ch, c, ref in self._lin:
            u += c * (sample[ch] - ref)
        return u

    def current_gain(self, sample: Mapping[str, float]) -> float:
        return sample[self.gain_channel] if self.gain_channel else self.gain

    def step(self, sample: Mapping[str, float]) -> float:
        u = 0.0
        for ch, c, ref in self._lin:
            u += c * (sample[ch] - ref)
        dyn = self.dynamics
        if self.switch_channel is not None and isinstance(dyn, GreyBox):
            y = dyn.step(u, sample[self.switch_channel])
        else:
            y = dyn.step(u)
        return (sample[self.gain_channel] if self.gain_channel else self.gain) * y

    def steady_state(self, sample: Mapping[str, float]) -> float:
        u = self.input_value(sample)
        dyn = self.dynamics
        if self.switch_channel is not None and isinstance(dyn, GreyBox):
            y = dyn.steady_state(u, sample[self.switch_channel])
        else:
            y = dyn.steady_state(u)
        return self.current_gain(sample) * y


class CompensationModel:
    """A list of terms stepped together once per sample; output in µm."""

    def __init__(self, terms: list[Term], period_s: float, name: str = "model",
                 description: str = "", provenance: dict[str, Any] | None = None) -> None:
        if not terms:
            raise ModelError(f"{name}: a model needs at least one term")
        names = [t.name for t in terms]
        dup = {n for n in names if names.count(n) > 1}
        if dup:
            raise ModelError(f"{name}: duplicate term name(s) {sorted(dup)}")
        if not (math.isfinite(period_s) and period_s > 0):
            raise ModelError(f"{name}.period_s: must be > 0 s, got {period_s!r}")
        self.terms = terms
        self.period_s = float(period_s)
        self.name = name
        self.description = description
        self.provenance: dict[str, Any] = dict(provenance or {})
        #: the probe estimator's settings the model file carries ([adaptation], learnt by
        #: `compd fit --adaptation`): `models.adaptation.AdaptationParams` fields
        self.adaptation: dict[str, Any] = {}
        self.contributions: list[float] = [0.0] * len(terms)
        self.references: dict[str, float] = {}
        #: the reference state the model was calibrated from (°C per relative input
        #: channel: the temperatures at which its growth is zero), empty when the
        #: model file does not say; `set_references` is what a running model uses
        self.calibration_reference: dict[str, float] = {}
        #: fallback models by the input channel whose loss each covers (a model on the
        #: remaining channels, fitted with this one: the model file's [[fallback]]);
        #: none reads the channel it stands in for
        self.fallbacks: dict[str, CompensationModel] = {}

    # -- structure ----------------------------------------------------------------------------

    @property
    def channels(self) -> set[str]:
        out: set[str] = set()
        for t in self.terms:
            out |= t.channels
        return out

    @property
    def reference_channels(self) -> set[str]:
        return {ch for t in self.terms if t.relative for ch in t.inputs}

    def check_channels(self, known: Iterable[str]) -> None:
        """Refuse a term that reads a channel the daemon does not have."""
        have = set(known)
        for t in self.terms:
            missing = sorted(t.channels - have)
            if missing:
                raise ModelError(f"term {t.name!r}: unknown channel(s) {missing}; "
                                 f"known channels: {sorted(have)}")

    def fresh(self) -> CompensationModel:
        """A model of the same description (terms, coefficients, calibration
        reference, fallbacks) with a state of its own, at rest and without a
        reference state set: the one to step, this one staying untouched."""
        out = copy.deepcopy(self)
        out.references = {}
        for t in out.terms:
            t._refs = out.references
            t._rebuild()
        out.reset()
        out.fallbacks = {lost: fb.fresh() for lost, fb in self.fallbacks.items()}
        return out

    # -- references and state -----------------------------------------------------------------

    def set_references(self, references: Mapping[str, float]) -> None:
        """Fix T_ref for every relative input channel (the reference state)."""
        missing = sorted(self.reference_channels - set(references))
        if missing:
            raise ModelError(f"{self.name}: no reference value for channel(s) {missing}")
        for ch in self.reference_channels:
            v = float(references[ch])
            if not math.isfinite(v):
                raise ModelError(f"{self.name}: reference for {ch!r} is not finite ({v!r})")
            self.references[ch] = v
        for t in self.terms:
            t._refs = self.references
            t._rebuild()

    def reset(self) -> None:
        for t in self.terms:
            t.dynamics.reset()
        self.contributions = [0.0] * len(self.terms)

    def steady_state(self, sample: Mapping[str, float]) -> float:
        """Put every term at the steady state matching `sample` (a warm machine)."""
        total = 0.0
        for i, t in enumerate(self.terms):
            y = t.steady_state(sample)
            self.contributions[i] = y
            total += y
        return total

    def step(self, sample: Mapping[str, float]) -> float:
        """Advance every term one sample; returns δZ in µm."""
        total = 0.0
        contributions = self.contributions
        for i, t in enumerate(self.terms):
            y = t.step(sample)
            contributions[i] = y
            total += y
        return total

    def export_state(self) -> dict[str, Any]:
        return {
            "references": dict(self.references),
            "terms": {t.name: t.dynamics.export_state() for t in self.terms},
        }

    def import_state(self, state: Mapping[str, Any]) -> None:
        terms = state.get("terms")
        refs = state.get("references")
        if not isinstance(terms, dict) or not isinstance(refs, dict):
            raise ModelError(f"{self.name}: state needs 'references' and 'terms' tables")
        unknown = sorted(set(terms) - {t.name for t in self.terms})
        if unknown:
            raise ModelError(f"{self.name}: state has unknown term(s) {unknown}")
        for t in self.terms:
            if t.name not in terms:
                raise ModelError(f"{self.name}: state lacks term {t.name!r}")
        self.set_references(refs)
        for t in self.terms:
            t.dynamics.import_state(terms[t.name])
