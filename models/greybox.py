"""Grey-box ODE model of a rotary-axis error (paper 002, docs/models.md §5).

One first-order ODE per error, input u1 = drive power (or axis speed) read
from the NC, explicit Euler at the sample period ``Ts`` (seconds)::

    dy/dt = u2·(p1·y + p2·(u1 + p3)) + (1 - u2)·(p4·y + p5·(u1 + p6))
    y(k)  = y(k-1) + Ts · f(y(k-1), u1(k), u2(k))

u2 ∈ {0, 1} switches between the two functional states (1 = moving, 0 =
standstill); without a switch only (p1, p2, p3) are used. y in µm, p1 and
p4 in 1/s. Worked number: p1 = -1e-4 1/s, p2 = 2e-4 µm/(s·kW), p3 = 0 at a
constant 5 kW settles at y = -p2·u/p1 = 10 µm.
"""

from __future__ import annotations

import math
from typing import Any

from models.errors import ModelError


class GreyBox:
    """Stateful Euler-integrated first-order ODE; `step(u1, u2) -> y` µm."""

    __slots__ = ("name", "p", "period_s", "switched", "y")

    def __init__(self, p: list[float], period_s: float, name: str = "greybox") -> None:
        self.name = name
        if len(p) not in (3, 6):
            raise ModelError(f"{name}.p: expected 3 parameters (p1..p3) or 6 with the u2 "
                             f"switch (p1..p6), got {len(p)}")
        values = [float(v) for v in p]
        if not all(math.isfinite(v) for v in values):
            raise ModelError(f"{name}.p: parameters must be finite, got {values!r}")
        if not (math.isfinite(period_s) and period_s > 0):
            raise ModelError(f"{name}: the sample period must be > 0 s, got {period_s!r}")
        self.p = values
        self.switched = len(values) == 6
        self.period_s = float(period_s)
        self.y = 0.0
        for label, rate in (("p1", values[0]),) + ((("p4", values[3]),) if self.switched else ()):
            factor = 1.0 + self.period_s * rate
            if not (rate < 0.0 and abs(factor) < 1.0):
                raise ModelError(
                    f"{name}.{label}: unstable: needs {label} < 0 and |1 + Ts·{label}| < 1 for the "
                    f"Euler step to settle (got {label} = {rate!r} 1/s, Ts = {self.period_s} s)")

    def step(self, u1: float, u2: float = 1.0) -> float:
        p1, p2, p3 = self.p[0], self.p[1], self.p[2]
        y = self.y
        if self.switched and u2 < 0.5:
            p4, p5, p6 = self.p[3], self.p[4], self.p[5]
            dy = p4 * y + p5 * (u1 + p6)
        else:
            dy = p1 * y + p2 * (u1 + p3)
        self.y = y + self.period_s * dy
        return self.y

    def reset(self) -> None:
        self.y = 0.0

    def steady_state(self, u1: float, u2: float = 1.0) -> float:
        if self.switched and u2 < 0.5:
            rate, gain, bias = self.p[3], self.p[4], self.p[5]
        else:
            rate, gain, bias = self.p[0], self.p[1], self.p[2]
        self.y = -gain * (u1 + bias) / rate
        return self.y

    @property
    def dc_gain(self) -> float:
        """µm per unit of u1 in the moving state."""
        return -self.p[1] / self.p[0]

    def export_state(self) -> dict[str, list[float]]:
        return {"y": [self.y]}

    def import_state(self, state: dict[str, Any]) -> None:
        y = state.get("y") if isinstance(state, dict) else None
        if not isinstance(y, list) or len(y) != 1 or not math.isfinite(float(y[0])):
            raise ModelError(f"{self.name}: state needs 'y' with one finite value, got {y!r}")
        self.y = float(y[0])
