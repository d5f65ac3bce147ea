"""The "shop" variant of the simulated machine: what a calibration meets on
a production machine tool, not on a bench.

The same heat network (`drivers.sim.plant`), seen through sixteen
temperature sensors placed as a machine builder places them:

- several nearly collinear (two on the bearing, motor and motor housing,
  bearing/motor flange), one with a 2.5 K calibration offset (a relative
  input does not care, a careless absolute model does);
- some irrelevant to the growth (coolant tank, electrical cabinet, hydraulic
  unit, a sensor by the door): slow processes of their own;
- none on the spindle shaft or the headstock casting: a heat path that no
  sensor sees directly (the shaft's growth is 2.7 µm/K, the largest term);
- every reading quantised to 0.1 K with 0.03 K noise.

The room drifts over days (a slow trend on top of the daily swing and its
random walk), the probe reads the growth with 0.3 µm noise, zeroed at the
record's first sample, and the record starts warm: at 14:00, the machine
running since 6:00. The spindle program is a
workday: random speed steps (every 20-60 min, 2,000-10,000 rpm, some idle
stops) from 6:00 to 22:00, standing at night (a cool-down every night).

Columns: ``time_s, spindle_rpm, t1_degC … t16_degC, dz_um`` (the names of the real
record in tests/data/fl_thermal).

A day with a change the model never saw (`ShopChange`, `compd sim --record …
--machine shop --change ambient+3K,heat+30% --change-at-h 24`): from the
record's hour `at_h` the room moves `ambient_k` kelvin away from where it was
heading (a ramp over `ramp_h`: an air conditioning set anew), and the spindle
bearing's losses are `heat_factor` times what they were (a bearing preloaded
harder after a rebuild). Both act on the plant, so every sensor that sees
them sees them; the seed's random streams are the same with and without the
change, so the two records differ only by it.
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from drivers.sim.ambient import Ambient
from drivers.sim.plant import PlantParams, ThermalPlant

SENSORS: tuple[str, ...] = tuple(f"t{i}_degC" for i in range(1, 17))
SHOP_COLUMNS: tuple[str, ...] = ("time_s", "spindle_rpm", *SENSORS, "dz_um")
#: room drift, K per day
DRIFT_K_PER_DAY = 0.8
#: hours the machine runs before the record starts
WARMUP_H = 8.0
#: the hour of day of the record's first sample (mid-shift: the machine is warm)
RECORD_START_HOUR = 14.0


def workday_speeds(seed: int, hours: float, start_hour: float) -> Callable[[float], float]:
    """Speed (rpm) at machine time t (s): steps in the day shift, 0 at night."""
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(11,)))
    steps: list[tuple[float, float]] = []
    t = 0.0
    while t < hours * 3600.0:
        hold = float(rng.uniform(20.0, 60.0)) * 60.0
        level = 0.0 if rng.random() < 0.15 else float(np.round(rng.uniform(2000, 10000), -2))
        steps.append((t, level))
        t += hold
    times = np.array([s for s, _ in steps])
    levels = [v for _, v in steps]

    def speed(t_s: float) -> float:
        hour = (start_hour + t_s / 3600.0) % 24.0
        if not 6.0 <= hour < 22.0:
            return 0.0
        return levels[max(0, int(np.searchsorted(times, t_s, side="right")) - 1)]

    return speed


@dataclass(frozen=True)
class ShopChange:
    """A change the model never saw, from the record's hour `at_h` on."""

    ambient_k: float = 0.0  # the room's shift, K (reached over ramp_h)
    heat_factor: float = 1.0  # the spindle bearing's losses times this
    at_h: float = 0.0  # hour of the record (0 = its first sample) the change starts
    ramp_h: float = 1.0  # hours the room takes to its new level

    def __post_init__(self) -> None:
        for name in ("ambient_k", "heat_factor", "at_h", "ramp_h"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"{name} must be finite")
        if not (abs(self.ambient_k) <= 20.0 and 0.0 < self.heat_factor <= 5.0
                and self.at_h >= 0.0 and self.ramp_h >= 0.0):
            raise ValueError("need |ambient_k| <= 20 K, 0 < heat_factor <= 5, at_h >= 0 "
                             "and ramp_h >= 0")


#: the day with a change the adaptation is judged on (docs/adaptation.md,
#: benchmarks/bench_adaptation.py): the room 3 K warmer and a heat source 30 % stronger
DAY_WITH_A_CHANGE = ShopChange(ambient_k=3.0, heat_factor=1.3)

_CHANGE_ITEM = re.compile(r"^(ambient)([+-]\d+(?:\.\d+)?)K$|^(heat)([+-]\d+(?:\.\d+)?)%$")


def parse_change(text: str, at_h: float = 0.0) -> ShopChange:
    """``ambient+3K,heat+30%`` (either or both, comma-separated) as a `ShopChange`;
    ValueError naming the bad item."""
    ambient_k, heat_pct, seen = 0.0, 0.0, set()
    for item in text.split(","):
        m = _CHANGE_ITEM.match(item.strip())
        if m is None:
            raise ValueError(f"bad change {item.strip()!r}: expected ambient±NK and/or "
                             "heat±N% (e.g. ambient+3K,heat+30%)")
        name = m.group(1) or m.group(3)
        if name in seen:
            raise ValueError(f"change {name!r} given twice")
        seen.add(name)
        if name == "ambient":
            ambient_k = float(m.group(2))
        else:
            heat_pct = float(m.group(4))
    return ShopChange(ambient_k=ambient_k, heat_factor=1.0 + heat_pct / 100.0, at_h=at_h)


class _DriftingRoom(Ambient):
    """The plant's room plus a slow trend of `DRIFT_K_PER_DAY` (and a change's shift
    from plant time `shift_from_s`, reached over `shift_ramp_s`)."""

    def __init__(self, room: Ambient, shift_k: float = 0.0, shift_from_s: float = 0.0,
                 shift_ramp_s: float = 0.0) -> None:
        self.__dict__.update(room.__dict__)
        self._shift = (shift_k, shift_from_s, shift_ramp_s)

    def __call__(self, t_s: float) -> float:
        out = super().__call__(t_s) + DRIFT_K_PER_DAY * t_s / 86400.0
        k, t0, ramp = self._shift
        if k and t_s > t0:
            out += k * (min(1.0, (t_s - t0) / ramp) if ramp > 0.0 else 1.0)
        return out


class _Slow:
    """An irrelevant sensor's own process: daily swing + random walk (K)."""

    def __init__(self, rng: np.random.Generator, amp: float, walk: float, phase: float) -> None:
        self.rng, self.amp, self.walk, self.phase, self.x = rng, amp, walk, phase, 0.0

    def __call__(self, t_s: float, dt_s: float) -> float:
        self.x += self.walk * math.sqrt(dt_s / 3600.0) * float(self.rng.standard_normal())
        self.x *= math.exp(-dt_s / (8 * 3600.0))
        return self.amp * math.sin(2 * math.pi * t_s / 86400.0 + self.phase) + self.x


def simulate_shop(hours: float, *, period_s: float = 60.0, seed: int = 0,
                  warmup_h: float = WARMUP_H, probe_noise_um: float = 0.3,
                  change: ShopChange | None = None) -> dict[str, np.ndarray]:
    """Sample the shop machine; columns as in `SHOP_COLUMNS`."""
    if not (period_s > 0.0 and hours > 0.0 and warmup_h >= 0.0):
        raise ValueError("need period_s > 0, hours > 0 and warmup_h >= 0")
    params = PlantParams(start_hour=(RECORD_START_HOUR - warmup_h) % 24.0, sensor_noise_k=0.0,
                         sensor_quantum_k=0.0)
    plant = ThermalPlant(seed=seed, params=params)
    change = change or ShopChange()
    change_s = (warmup_h + change.at_h) * 3600.0  # plant time of the change
    plant.ambient = _DriftingRoom(plant.ambient, change.ambient_k, change_s,
                                  change.ramp_h * 3600.0)
    hotter = dataclasses.replace(params, bearing_loss_a_w=params.bearing_loss_a_w
                                 * change.heat_factor, bearing_loss_b_w=params.bearing_loss_b_w
                                 * change.heat_factor)
    speed = workday_speeds(seed, hours + warmup_h, params.start_hour)
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(12,)))
    slow = [_Slow(rng, a, w, p) for a, w, p in ((0.6, 0.4, 0.3), (1.5, 0.2, 2.0),
                                                 (0.4, 0.6, 4.0), (2.0, 0.3, 1.0))]
    t = 0.0
    for _ in range(math.floor(warmup_h * 3600.0 / period_s + 1e-9)):
        plant.step(period_s, speed(t))
        t += period_s
    n = math.floor(hours * 3600.0 / period_s + 1e-9) + 1
    out = {c: np.empty(n) for c in SHOP_COLUMNS}
    g0 = plant.growth_um()
    x = plant.temperatures()
    cabinet, base = x["ambient"] + 3.0, x["column"]
    a_cab, a_base = 1.0 - math.exp(-period_s / 5400.0), 1.0 - math.exp(-period_s / 7200.0)
    for k in range(n):
        if k:
            if t >= change_s - 1e-6:
                plant.params = hotter
            plant.step(period_s, speed(t))
            t += period_s
        x = plant.temperatures()
        amb = x["ambient"]
        cabinet += a_cab * (amb + 3.0 + 6e-4 * plant.speed_rpm - cabinet)
        base += a_base * (x["column"] - base)
        s = [slow_k(t, period_s) for slow_k in slow]
        true = (x["bearing"], x["bearing"] + 0.15, x["motor"],
                0.8 * x["motor"] + 0.2 * x["headstock"], 0.5 * x["bearing"] + 0.5 * x["motor"],
                x["column"], x["column"] + 2.5, base, x["table"], x["table"] + 0.05 * s[0],
                amb, amb + 0.6 * s[1] + 0.3, 20.0 + s[2], cabinet + s[0], 24.0 + s[3],
                amb + s[1])
        noise = rng.normal(0.0, 0.03, 16)
        for i, (name, v) in enumerate(zip(SENSORS, true, strict=True)):
            out[name][k] = round(round((v + noise[i]) / 0.1) * 0.1, 6)
        out["spindle_rpm"][k] = plant.speed_rpm
        out["time_s"][k] = k * period_s
        out["dz_um"][k] = plant.growth_um() - g0
    out["dz_um"] = out["dz_um"] + probe_noise_um * rng.standard_normal(n)
    return out


def write_shop_record(path: str, columns: dict[str, np.ndarray]) -> int:
    """Write a shop record CSV (temperatures 0.1 K, displacement 0.001 µm)
    through a temporary name; return the number of rows."""
    import os
    from pathlib import Path

    target = Path(path)
    tmp = target.with_name(target.name + ".part")
    n = len(columns["time_s"])
    with tmp.open("w", encoding="ascii", newline="") as f:
        f.write(",".join(SHOP_COLUMNS) + "\n")
        for k in range(n):
            row = [f"{columns['time_s'][k]:.3f}", f"{columns['spindle_rpm'][k]:.0f}"]
            row += [f"{columns[s][k]:.1f}" for s in SENSORS]
            row.append(f"{columns['dz_um'][k]:.3f}")
            f.write(",".join(row) + "\n")
    os.replace(tmp, target)
    return n
