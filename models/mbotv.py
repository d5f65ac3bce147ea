"""Model based on temperature variation, MBOTV (paper 003, docs/models.md §6).

Input T = T_spindle_front_bearing - T_column (K, relative to the reference
state), sample period t (s)::

    Tv(i)  = (T(i) - T(i-1)) / t
    Ta(i)  = (Tv(i) - Tv(i-1)) / t
    zss(i) = α·T(i) + β·Tv(i) + δ·Ta(i)
    z(i)   = k·z(i-1) + (1 - k)·zss(i)          k = exp(-t/τ)
    zf(i)  = γ·zf(i-1) + (1 - γ)·z(i)

The paper names α, β (the response coefficients), k and γ; its equation (5)
is not legible in our copy, so the acceleration coefficient δ is kept
separate and defaults to 0. Everything is linear: a constant T settles at
zf = α·T. Worked number: α = 3 µm/K at T = 2 K settles at 6 µm.
"""

from __future__ import annotations

import math
from typing import Any

from models.errors import ModelError


class Mbotv:
    """Stateful MBOTV filter: `step(T) -> zf` µm."""

    __slots__ = ("_primed", "alpha", "beta", "delta", "gamma", "k", "name", "period_s",
                 "t_prev", "tv_prev", "z", "zf")

    def __init__(self, alpha: float, beta: float, k: float, gamma: float, period_s: float,
                 delta: float = 0.0, name: str = "mbotv") -> None:
        self.name = name
        for label, v in (("alpha", alpha), ("beta", beta), ("delta", delta), ("k", k),
                         ("gamma", gamma), ("period_s", period_s)):
            if not math.isfinite(v):
                raise ModelError(f"{name}.{label}: must be finite, got {v!r}")
        if not 0.0 <= k < 1.0:
            raise ModelError(f"{name}.k: must lie in [0, 1) for the lag to settle, got {k!r}")
        if not 0.0 <= gamma < 1.0:
            raise ModelError(f"{name}.gamma: must lie in [0, 1) for the filter to settle, "
                             f"got {gamma!r}")
        if period_s <= 0:
            raise ModelError(f"{name}.period_s: must be > 0, got {period_s!r}")
        self.alpha, self.beta, self.delta = float(alpha), float(beta), float(delta)
        self.k, self.gamma, self.period_s = float(k), float(gamma), float(period_s)
        self.reset()

    @classmethod
    def from_tau(cls, alpha: float, beta: float, tau_s: float, gamma: float, period_s: float,
                 delta: float = 0.0, name: str = "mbotv") -> Mbotv:
        if not (math.isfinite(tau_s) and tau_s > 0):
            raise ModelError(f"{name}.tau_s: must be > 0, got {tau_s!r}")
        return cls(alpha, beta, math.exp(-period_s / tau_s), gamma, period_s, delta, name)

    def reset(self) -> None:
        self.t_prev = 0.0
        self.tv_prev = 0.0
        self.z = 0.0
        self.zf = 0.0
        self._primed = False

    def step(self, T: float) -> float:
        t = self.period_s
        tv = (T - self.t_prev) / t if self._primed else 0.0
        ta = (tv - self.tv_prev) / t if self._primed else 0.0
        zss = self.alpha * T + self.beta * tv + self.delta * ta
        self.z = self.k * self.z + (1.0 - self.k) * zss
        self.zf = self.gamma * self.zf + (1.0 - self.gamma) * self.z
        self.t_prev, self.tv_prev, self._primed = T, tv, True
        return self.zf

    def steady_state(self, T: float) -> float:
        self.t_prev, self.tv_prev, self._primed = T, 0.0, True
        self.z = self.zf = self.alpha * T
        return self.zf

    @property
    def dc_gain(self) -> float:
        return self.alpha

    def export_state(self) -> dict[str, list[float]]:
        return {"mbotv": [self.t_prev, self.tv_prev, self.z, self.zf, float(self._primed)]}

    def import_state(self, state: dict[str, Any]) -> None:
        v = state.get("mbotv") if isinstance(state, dict) else None
        if not isinstance(v, list) or len(v) != 5 or not all(
                isinstance(x, int | float) and math.isfinite(x) for x in v):
            raise ModelError(f"{self.name}: state needs 'mbotv' with 5 finite values, got {v!r}")
        self.t_prev, self.tv_prev, self.z, self.zf = (float(x) for x in v[:4])
        self._primed = bool(v[4])
