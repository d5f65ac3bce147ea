"""Room temperature for the simulated machine: a daily sinusoid plus a slow,
mean-reverting random walk, seeded.

    T_amb(t) = T_mean + A_day · sin(2π (h(t) - 9) / 24) + w(t)      [°C]
    h(t)     = start_hour + t / 3600                                 (clock hour; peak at 15:00)
    w        Ornstein-Uhlenbeck process, stationary std σ_w, time constant τ_w,
             sampled exactly on a knot every `knot_s` seconds, linear in between.

Because the walk lives on a fixed knot grid, T_amb is a function of machine
time alone (for a given seed): stepping the plant in 1 s or 10 s steps sees the
same room. Worked number: start 06:00, A_day = 1 K, σ_w = 0 → T_amb(9 h) =
T_mean + 1 K (15:00), T_amb(0) = T_mean - 0.707 K.
"""

from __future__ import annotations

import math

import numpy as np


class Ambient:
    """Room temperature as a function of machine time (seconds)."""

    def __init__(self, rng: np.random.Generator, *, mean_c: float = 20.0,
                 day_amplitude_k: float = 1.0, start_hour: float = 6.0,
                 walk_std_k: float = 0.3, walk_tau_s: float = 3 * 3600.0,
                 knot_s: float = 60.0) -> None:
        if knot_s <= 0.0 or walk_tau_s <= 0.0 or walk_std_k < 0.0:
            raise ValueError("knot_s and walk_tau_s must be > 0, walk_std_k >= 0")
        self._rng = rng
        self.mean_c = float(mean_c)
        self.day_amplitude_k = float(day_amplitude_k)
        self.start_hour = float(start_hour)
        self._knot_s = float(knot_s)
        self._decay = math.exp(-knot_s / walk_tau_s)
        self._kick = walk_std_k * math.sqrt(1.0 - self._decay * self._decay)
        first = float(rng.normal(0.0, walk_std_k)) if walk_std_k > 0.0 else 0.0
        self._knots: list[float] = [first]

    def _extend(self, index: int) -> None:
        """Make sure knots 0..index exist (drawn in one-day chunks)."""
        knots = self._knots
        while len(knots) <= index:
            n = max(1440, index + 1 - len(knots))
            kicks = self._rng.standard_normal(n) * self._kick
            w = knots[-1]
            decay = self._decay
            for k in kicks.tolist():
                w = w * decay + k
                knots.append(w)

    def walk(self, t_s: float) -> float:
        """The random-walk part w(t), K."""
        if t_s <= 0.0:
            return self._knots[0]
        pos = t_s / self._knot_s
        i = int(pos)
        self._extend(i + 1)
        frac = pos - i
        return self._knots[i] * (1.0 - frac) + self._knots[i + 1] * frac

    def day(self, t_s: float) -> float:
        """The daily sinusoid, K (relative to the mean)."""
        hour = self.start_hour + t_s / 3600.0
        return self.day_amplitude_k * math.sin(2.0 * math.pi * (hour - 9.0) / 24.0)

    def __call__(self, t_s: float) -> float:
        return self.mean_c + self.day(t_s) + self.walk(t_s)
