"""A ball-screw axis whose growth depends on the position along the travel.

The X axis of a machine tool grows in two ways: the whole axis moves (the
column and the spindle warm up, the screw's fixed bearing housing grows)
and the screw itself lengthens from its fixed bearing, so the error grows
with the distance from it. At axis position x (mm), with x0 the reference
position (the fixed bearing, 0 mm by default):

    e(x, t) = a(t) + b(t) · (x - x0) / 1000        (µm; b in µm/m)

    a = k_column · Δcolumn + k_bearing · Δbearing + k_ambient · Δambient
    b = alpha_screw · Δscrew                           (steel: 11.5 µm/m/K)

with Δ a node's rise over its value at t = 0 (the machine in equilibrium
with the room). Noise-free, e is exactly linear in x.

Four lumped nodes (°C), heat capacities C (J/K), the same energy balance and
exact zero-order-hold stepping as `drivers.sim.plant`:

    0 nut      ball nut and the screw under it       (sensor "nut")
    1 bearing  the screw's fixed bearing              (sensor "screw_bearing")
    2 screw    the screw body (its mean temperature)  (no sensor)
    3 column   column + spindle housing               (sensor "column")

Heat sources: the axis's motion heats the nut and the bearing in proportion
to duty (fraction of time the axis moves) times traverse speed,

    q_nut = nut_loss_w · duty · speed / 10,000 mm/min
    q_bearing = bearing_loss_w · duty · speed / 10,000 mm/min

and the spindle heats the column, q_column = column_loss_w · rpm / 10,000.
The screw warms only through the nut and the bearing: the slope follows
the axis's duty, the value mostly the spindle.

Program (`axis_workday`): random blocks of 20-60 min, each with its own
spindle speed, axis duty and traverse speed (some blocks idle), seeded;
a different seed is a different duty cycle.

Measurement: every row the displacement is measured at each position (as a
laser interferometer or a ballbar at positions along the travel records it),
zeroed at the record's first row, with `probe_noise_um` noise per reading;
temperatures quantised to 0.1 K with 0.03 K noise, as in the plant.

Columns: ``time_s, spindle_rpm, axis_duty, axis_speed_mm_min, nut,
screw_bearing, column, ambient`` then one ``dx_at_<x>mm_um`` per position
(`position_column`; x in mm to the micrometre, without trailing zeros:
``dx_at_0mm_um``, ``dx_at_200mm_um``,
``dx_at_-50mm_um``, ``dx_at_12.5mm_um``).
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drivers.sim.ambient import Ambient
from drivers.sim.plant import exact_zoh

NODES: tuple[str, ...] = ("nut", "bearing", "screw", "column")
_N, _BR, _S, _C = range(4)
#: the temperature columns of a record (the measured nodes and the room)
TEMPERATURES: tuple[str, ...] = ("nut", "screw_bearing", "column", "ambient")
#: the record's columns before the position columns
HEAD_COLUMNS: tuple[str, ...] = ("time_s", "spindle_rpm", "axis_duty", "axis_speed_mm_min",
                                 *TEMPERATURES)
#: five positions along an 800 mm travel, the fixed bearing at 0 mm
DEFAULT_POSITIONS_MM: tuple[float, ...] = (0.0, 200.0, 400.0, 600.0, 800.0)

_POSITION_RE = re.compile(r"^dx_at_(-?\d+(?:\.\d+)?)mm_um$")


def position_column(x_mm: float) -> str:
    """The record's column of the displacement measured at `x_mm`, the position
    written to 0.001 mm without trailing zeros (never an exponent: 1e-05 mm is
    ``dx_at_0mm_um``, 1234.5678 mm ``dx_at_1234.568mm_um``)."""
    if not math.isfinite(x_mm):
        raise ValueError(f"a position must be finite, got {x_mm!r}")
    text = f"{round(x_mm, 3) + 0.0:.3f}".rstrip("0").rstrip(".")
    return f"dx_at_{'0' if text == '-0' else text}mm_um"


def parse_position_column(name: str) -> float | None:
    """The position (mm) a column ``dx_at_<x>mm_um`` names; None for any other name."""
    m = _POSITION_RE.match(name)
    return float(m.group(1)) if m else None


@dataclass(frozen=True)
class BallscrewParams:
    """Every constant of the ball-screw machine, with its unit in the name."""

    # heat capacities, J/K
    c_nut_j_k: float = 4_000.0
    c_bearing_j_k: float = 6_000.0
    c_screw_j_k: float = 20_000.0
    c_column_j_k: float = 600_000.0
    # conductances between nodes and to the room, W/K
    g_nut_screw_w_k: float = 5.0
    g_bearing_screw_w_k: float = 3.0
    g_nut_ambient_w_k: float = 2.0
    g_bearing_ambient_w_k: float = 2.5
    g_screw_ambient_w_k: float = 4.0
    g_column_ambient_w_k: float = 40.0
    # heat sources at full duty and 10,000 mm/min (axis), 10,000 rpm (spindle), W
    nut_loss_w: float = 30.0
    bearing_loss_w: float = 10.0
    column_loss_w: float = 200.0
    # growth: the value (µm/K) and the screw's strain (µm/m/K)
    k_column_um_k: float = 3.0
    k_bearing_um_k: float = 1.5
    k_ambient_um_k: float = 0.5
    alpha_screw_um_m_k: float = 11.5
    x0_mm: float = 0.0
    # room
    ambient_mean_c: float = 20.0
    ambient_day_amplitude_k: float = 1.0
    ambient_walk_std_k: float = 0.3
    ambient_walk_tau_s: float = 3 * 3600.0
    start_hour: float = 6.0
    # sensors and integration
    sensor_noise_k: float = 0.03
    sensor_quantum_k: float = 0.1
    substep_s: float = 10.0


#: the machine's state at one time: (spindle_rpm, axis_duty, axis_speed_mm_min)
AxisProgram = Callable[[float], tuple[float, float, float]]


def axis_workday(seed: int, hours: float) -> AxisProgram:
    """Random 20-60 min blocks of spindle speed, axis duty and traverse speed
    (15 % of the blocks idle), seeded: a different seed is a different day."""
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(21,)))
    starts: list[float] = []
    levels: list[tuple[float, float, float]] = []
    t = 0.0
    while t <= hours * 3600.0:
        starts.append(t)
        if rng.random() < 0.15:
            levels.append((0.0, 0.0, 0.0))
        else:
            levels.append((float(np.round(rng.uniform(0.0, 10_000.0), -2)),
                           float(np.round(rng.uniform(0.05, 0.9), 2)),
                           float(np.round(rng.uniform(2_000.0, 20_000.0), -2))))
        t += float(rng.uniform(20.0, 60.0)) * 60.0
    times = np.array(starts)

    def program(t_s: float) -> tuple[float, float, float]:
        return levels[max(0, int(np.searchsorted(times, t_s, side="right")) - 1)]

    return program


def constant_program(spindle_rpm: float, duty: float, speed_mm_min: float) -> AxisProgram:
    """The same spindle speed, axis duty and traverse speed all along."""
    return lambda _t: (spindle_rpm, duty, speed_mm_min)


def _discretise(p: BallscrewParams, h_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact ZOH (Φ, Γ) of C x' = -L x + G u, u = (q_nut, q_bearing, q_column, T_amb)."""
    links = ((_N, _S, p.g_nut_screw_w_k), (_BR, _S, p.g_bearing_screw_w_k))
    to_room = np.array([p.g_nut_ambient_w_k, p.g_bearing_ambient_w_k, p.g_screw_ambient_w_k,
                        p.g_column_ambient_w_k])
    L = np.diag(to_room)
    for i, j, g in links:
        L[i, i] += g
        L[j, j] += g
        L[i, j] -= g
        L[j, i] -= g
    G = np.zeros((4, 4))
    G[_N, 0] = G[_BR, 1] = G[_C, 2] = 1.0
    G[:, 3] = to_room
    cap = np.array([p.c_nut_j_k, p.c_bearing_j_k, p.c_screw_j_k, p.c_column_j_k])
    if np.any(cap <= 0.0) or np.any(to_room <= 0.0):
        raise ValueError("heat capacities and conductances to the room must be > 0")
    return exact_zoh(L, G, cap, h_s)


def simulate_ballscrew(hours: float, *, period_s: float = 300.0, seed: int = 0,
                       program: AxisProgram | None = None,
                       positions_mm: Sequence[float] = DEFAULT_POSITIONS_MM,
                       params: BallscrewParams | None = None,
                       probe_noise_um: float = 0.5) -> dict[str, np.ndarray]:
    """Sample the ball-screw machine every `period_s` for `hours` from rest.

    Returns the record's columns (`HEAD_COLUMNS` and one `position_column` per
    position) plus the truth: ``value_um`` (a, at x0) and ``slope_um_m`` (b).
    Row k holds the state at t = k·period_s; its program values are the ones
    held over the period ending there (row 0: at rest)."""
    p = params if params is not None else BallscrewParams()
    if not (period_s > 0.0 and hours > 0.0 and math.isfinite(period_s * hours)):
        raise ValueError("need period_s > 0 and hours > 0")
    if probe_noise_um < 0.0:
        raise ValueError("probe_noise_um must be >= 0")
    names = [position_column(x) for x in positions_mm]
    if not names or len(set(names)) != len(names):
        raise ValueError(f"need one or more positions distinct to 0.001 mm, got "
                         f"{list(positions_mm)}")
    prog = program if program is not None else axis_workday(seed, hours)
    ambient_seq, sensor_seq, probe_seq = np.random.SeedSequence(seed).spawn(3)
    room = Ambient(np.random.default_rng(ambient_seq), mean_c=p.ambient_mean_c,
                   day_amplitude_k=p.ambient_day_amplitude_k, start_hour=p.start_hour,
                   walk_std_k=p.ambient_walk_std_k, walk_tau_s=p.ambient_walk_tau_s)
    noise = np.random.default_rng(sensor_seq)
    probe = np.random.default_rng(probe_seq)
    n_sub = max(1, math.ceil(period_s / p.substep_s - 1e-9))
    h = period_s / n_sub
    Phi, Gamma = _discretise(p, h)
    n = math.floor(hours * 3600.0 / period_s + 1e-9) + 1
    amb0 = room(0.0)
    x = np.full(4, amb0)
    out = {c: np.empty(n) for c in (*HEAD_COLUMNS, "value_um", "slope_um_m")}
    state = (0.0, 0.0, 0.0)
    t = 0.0
    q = p.sensor_quantum_k
    for k in range(n):
        if k:
            state = prog(t)
            rpm, duty, speed = state
            move = duty * speed / 10_000.0
            u = np.array([p.nut_loss_w * move, p.bearing_loss_w * move,
                          p.column_loss_w * rpm / 10_000.0, 0.0])
            for i in range(n_sub):
                u[3] = room(t + (i + 0.5) * h)
                x = Phi @ x + Gamma @ u
            t = k * period_s
        amb = room(t)
        d = x - amb0
        out["time_s"][k] = t
        out["spindle_rpm"][k], out["axis_duty"][k], out["axis_speed_mm_min"][k] = state
        true = (x[_N], x[_BR], x[_C], amb)
        sensed = np.asarray(true) + p.sensor_noise_k * noise.standard_normal(4)
        for name, v in zip(TEMPERATURES, sensed, strict=True):
            out[name][k] = round(round(v / q) * q, 6) if q > 0.0 else float(v)
        out["value_um"][k] = (p.k_column_um_k * d[_C] + p.k_bearing_um_k * d[_BR]
                              + p.k_ambient_um_k * (amb - amb0))
        out["slope_um_m"][k] = p.alpha_screw_um_m_k * d[_S]
    for x_mm in positions_mm:
        true_e = out["value_um"] + out["slope_um_m"] * (x_mm - p.x0_mm) / 1000.0
        out[position_column(x_mm)] = true_e + probe_noise_um * probe.standard_normal(n)
    return out


def write_ballscrew_record(path: str | os.PathLike[str], columns: dict[str, np.ndarray],
                           positions_mm: Sequence[float] = DEFAULT_POSITIONS_MM) -> int:
    """Write the record CSV (temperatures 0.1 K, displacements 0.001 µm) through a
    temporary name; return the number of rows."""
    names = [*HEAD_COLUMNS, *(position_column(x) for x in positions_mm)]
    fmts = ["{:.3f}", "{:.0f}", "{:.3f}", "{:.0f}", *("{:.1f}" for _ in TEMPERATURES),
            *("{:.3f}" for _ in positions_mm)]
    row_fmt = ",".join(fmts) + "\n"
    target = Path(path)
    tmp = target.with_name(target.name + ".part")
    n = 0
    with tmp.open("w", encoding="ascii", newline="") as f:
        f.write(",".join(names) + "\n")
        for row in zip(*(np.asarray(columns[c], dtype=np.float64).tolist() for c in names),
                       strict=True):
            f.write(row_fmt.format(*row))
            n += 1
    os.replace(tmp, target)
    return n
