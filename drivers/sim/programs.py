"""Test programs for the simulated machine (ISO 230-3 and the papers).

A program is a function of machine time (s) returning the spindle speed (rpm),
with a natural duration; after its end the spindle stands (0 rpm). A program
may also ask for a livelier room (the ETVE test), applied with
`Program.plant_params`.

- `constant`: ISO 230-3 heat-up at one speed (default 9,000 rpm for 4 h),
  then a cool-down at 0 rpm (4 h): the calibration run of papers 000/003.
- `spectrum`: the speed changes every 30 min to a seeded random level between
  500 and 10,000 rpm (rounded to 100 rpm): the verification run.
- `etve`: environmental temperature variation error test: spindle at rest for
  24 h while the room swings ±3 K.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from drivers.sim.plant import PlantParams

HOUR_S = 3600.0


@dataclass(frozen=True)
class Program:
    """A spindle-speed schedule: `program(t_s) -> rpm`."""

    name: str
    duration_s: float
    speed: Callable[[float], float]
    #: cutting load fraction (0..1) held through the program
    load: float = 0.0
    #: daily room swing the program asks for (None: the plant's own)
    ambient_day_amplitude_k: float | None = None

    def __call__(self, t_s: float) -> float:
        if t_s < 0.0 or t_s >= self.duration_s:
            return 0.0
        return self.speed(t_s)

    def plant_params(self, base: PlantParams | None = None) -> PlantParams:
        """`base` with the room this program needs."""
        params = base if base is not None else PlantParams()
        if self.ambient_day_amplitude_k is None:
            return params
        return dataclasses.replace(params, ambient_day_amplitude_k=self.ambient_day_amplitude_k)


def constant(speed_rpm: float = 9_000.0, heat_h: float = 4.0, cool_h: float = 4.0) -> Program:
    """Heat-up at `speed_rpm` for `heat_h` hours, then 0 rpm for `cool_h` hours."""
    if heat_h < 0.0 or cool_h < 0.0 or heat_h + cool_h <= 0.0:
        raise ValueError("heat_h and cool_h must be >= 0 and not both 0")
    heat_s = heat_h * HOUR_S

    def speed(t_s: float) -> float:
        return speed_rpm if t_s < heat_s else 0.0

    return Program("constant", (heat_h + cool_h) * HOUR_S, speed)


def spectrum(seed: int = 0, hours: float = 12.0, step_min: float = 30.0,
             low_rpm: float = 500.0, high_rpm: float = 10_000.0) -> Program:
    """A new seeded random speed level every `step_min` minutes."""
    if hours <= 0.0 or step_min <= 0.0 or not 0.0 <= low_rpm <= high_rpm:
        raise ValueError("need hours > 0, step_min > 0 and 0 <= low_rpm <= high_rpm")
    step_s = step_min * 60.0
    n = int(np.ceil(hours * HOUR_S / step_s))
    rng = np.random.default_rng(seed)
    levels = (np.round(rng.uniform(low_rpm, high_rpm, n) / 100.0) * 100.0).clip(low_rpm, high_rpm)
    table: list[float] = [float(v) for v in levels]

    def speed(t_s: float) -> float:
        return table[min(int(t_s // step_s), n - 1)]

    return Program("spectrum", hours * HOUR_S, speed)


def etve(hours: float = 24.0, amplitude_k: float = 3.0) -> Program:
    """Spindle at rest while the room swings ±`amplitude_k` over the day."""
    if hours <= 0.0:
        raise ValueError("hours must be > 0")

    def speed(t_s: float) -> float:
        return 0.0

    return Program("etve", hours * HOUR_S, speed, ambient_day_amplitude_k=amplitude_k)


PROGRAM_NAMES: tuple[str, ...] = ("constant", "spectrum", "etve")


def make_program(name: str, *, seed: int = 0, hours: float | None = None) -> Program:
    """A program by name; `hours` overrides its natural duration (for
    `constant`, half heat-up, half cool-down)."""
    if name == "constant":
        return constant() if hours is None else constant(heat_h=hours / 2, cool_h=hours / 2)
    if name == "spectrum":
        return spectrum(seed=seed) if hours is None else spectrum(seed=seed, hours=hours)
    if name == "etve":
        return etve() if hours is None else etve(hours=hours)
    raise ValueError(f"unknown program {name!r}; known: {list(PROGRAM_NAMES)}")
