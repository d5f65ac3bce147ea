"""`[adaptation]` as the cycle needs it (`compd.core.adaptation` uses it)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from models.adaptation import AdaptationParams

__all__ = ["AdaptationSettings"]


@dataclass(frozen=True)
class AdaptationSettings:
    """The mode ("shadow": estimated and recorded; "apply": added to the model
    output), what the probe measures, the estimator's settings, and the probes over
    which the guard "no model worse than none" judges the compensation (0: off)."""

    mode: Literal["shadow", "apply"]
    measures: Literal["residual", "displacement"]
    params: AdaptationParams
    guard_window: int = 3
