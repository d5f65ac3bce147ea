"""``[channels.NAME]``: one input's address, unit, range and the checks that judge its
values (rate, stale, stuck)."""

from __future__ import annotations

import math
from typing import Annotated, Any

from pydantic import Field, ValidationInfo, field_validator

from compd.config.section import PositiveS, Section, StrictFloat

#: channel units the daemon knows (what a value in a channel means)
UNITS: tuple[str, ...] = ("degC", "K", "rpm", "kW", "W", "um", "mm", "ratio", "percent",
                          "A", "Nm")

#: channel units that are temperatures (their moves count for stuck_delta_k)
TEMPERATURE_UNITS: tuple[str, ...] = ("degC", "K")

#: stuck_delta_k of a temperature channel with stuck_after_s and no stuck_delta_k
DEFAULT_STUCK_DELTA_K = 2.0


class ChannelSection(Section):
    #: validated against the protocol's address model by `compd.config.loader`
    address: dict[str, Any]
    unit: str
    range: Annotated[tuple[StrictFloat, StrictFloat], Field(strict=False)]
    max_rate_per_s: PositiveS | None = None
    stale_after_s: PositiveS | None = None
    stuck_after_s: PositiveS | None = None
    #: stuck when unchanged while another temperature channel moved by more than
    #: this (K) since it last changed; default DEFAULT_STUCK_DELTA_K for a
    #: temperature channel with stuck_after_s; inf turns it off. Not for a
    #: sensor that may rightly stay put while the machine heats (the hall's
    #: ambient): see compd.core.validation
    stuck_delta_k: Annotated[float, Field(gt=0.0)] | None = None

    @field_validator("stuck_delta_k")
    @classmethod
    def _stuck_delta(cls, v: float | None, info: ValidationInfo) -> float | None:
        if v is not None and info.data.get("unit", TEMPERATURE_UNITS[0]) not in TEMPERATURE_UNITS:
            raise ValueError("applies to temperature channels only (unit degC or K): "
                             "it compares how far other temperatures moved")
        return v

    @property
    def temperature(self) -> bool:
        return self.unit in TEMPERATURE_UNITS

    @property
    def effective_stuck_delta_k(self) -> float | None:
        """The heat criterion's threshold in K, None when off."""
        v = self.stuck_delta_k
        if v is None and self.stuck_after_s is not None and self.temperature:
            v = DEFAULT_STUCK_DELTA_K
        return v if v is not None and math.isfinite(v) else None

    @field_validator("unit")
    @classmethod
    def _unit(cls, v: str) -> str:
        if v not in UNITS:
            raise ValueError(f"unknown unit {v!r}; known: {', '.join(UNITS)}")
        return v

    @field_validator("range")
    @classmethod
    def _range(cls, v: tuple[float, float]) -> tuple[float, float]:
        lo, hi = v
        if not (math.isfinite(lo) and math.isfinite(hi)):
            raise ValueError("bounds must be finite numbers")
        if not lo < hi:
            raise ValueError("lower bound must be below upper bound")
        return v
