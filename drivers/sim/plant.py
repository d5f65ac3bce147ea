"""The simulated machine tool's thermal behaviour: six lumped nodes.

This is deliberately *not* one of compd's model structures (no single
discrete transfer function): a small heat network whose Z growth a model has
to learn from the sensors, as on a real machine.

Nodes (temperatures x, °C) and heat capacities C (J/K):

    0 bearing    spindle front bearing ring + housing     (sensor "bearing")
    1 motor      spindle motor stator                     (sensor "motor")
    2 headstock  spindle housing casting                  (no sensor)
    3 shaft      spindle shaft + rotor                    (no sensor; lags the bearing)
    4 column     column                                   (sensor "column")
    5 table      rotary table bearing                     (sensor "table")

Energy balance per node i (W), conductances g_ij between nodes, g_ia to ambient:

    C_i dx_i/dt = q_i + Σ_j g_ij (x_j - x_i) + g_ia (T_amb - x_i) + c_i (T_cool - x_i)

Heat sources with n_k = speed / 1000 rpm, load ∈ [0, 1]:

    q_bearing = a_b · n_k^1.5 + b_b · n_k                          (rolling + viscous loss, W)
    P_cut     = load · P_rated · min(1, n / n_base)                 (kW)
    q_motor   = a_m · n_k² + b_m · n_k + (1/η - 1) · P_cut · 1000   (iron/windage + copper, W)
    power_kw  = P_cut + (q_bearing + q_motor) / 1000

The spindle cooler (optional, `cooler_enabled`) switches on when the true
bearing temperature exceeds `cooler_on_c` and off below `cooler_off_c`
(hysteresis); while on it adds the conductances c_i to the coolant at
T_cool = T_amb + `coolant_offset_k`.

Integration: the network is linear between switchings, x' = A x + B u with
u = (q_bearing, q_motor, T_amb, T_cool) held over a sub-step h ≤ `substep_s`;
x(k+1) = Φ x(k) + Γ u(k) with Φ = e^{Ah}, Γ = A⁻¹(Φ - I)B computed exactly
from a symmetric eigen-decomposition (C^{½} A C^{-½} is symmetric), cached
per (h, cooler state).

Z growth at the tool (µm, positive = tool towards the workpiece), with Δ the
rise of a node over its value at t = 0 (machine in equilibrium with the room):

    growth = k_s Δshaft + k_h Δheadstock + k_c Δcolumn
             + k_g (Δcolumn - Δambient) + k_t Δtable + k_nl Δshaft |Δshaft|

(shaft elongation pushes the nose down; column growth lifts it; a column
warmer than the room tilts; the table rises towards the tool.)

Sensors: node temperature + N(0, σ) noise, quantised to 0.1 K (as on the
controls of the papers); `error_um = growth_um - offset_um`.

Worked number (default parameters, 20 °C room without drift): 4 h at
9,000 rpm idle gives q_bearing = 6·27 + 5·9 = 207 W, q_motor = 4·81 + 20·9 =
504 W, power 0.71 kW. Cooler off: the bearing rises +20.7 K, the motor
+25.7 K, the shaft +18.2 K (63 % of their final rise after ≈ 50-70 min), the
column +1.0 K (63 % after ≈ 5 h) and the growth reaches ≈ 57 µm; with the
cooler (on above 31 °C) the bearing holds near 30 °C and the growth plateaus
at ≈ 24 µm. A day of the default room (±1 K, walk σ 0.3 K) moves the growth
by a few µm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from drivers.sim.ambient import Ambient

#: node order of the state vector
NODES: tuple[str, ...] = ("bearing", "motor", "headstock", "shaft", "column", "table")
_B, _M, _H, _S, _C, _T = range(6)
SENSOR_NODES: tuple[tuple[str, int], ...] = (("bearing", _B), ("motor", _M),
                                             ("column", _C), ("table", _T))
MAX_SPEED_RPM = 10_000.0


@dataclass(frozen=True)
class PlantParams:
    """Every physical constant of the plant, with its unit in the name."""

    # heat capacities, J/K
    c_bearing_j_k: float = 12_000.0
    c_motor_j_k: float = 40_000.0
    c_headstock_j_k: float = 180_000.0
    c_shaft_j_k: float = 20_000.0
    c_column_j_k: float = 900_000.0
    c_table_j_k: float = 300_000.0
    # conductances between nodes, W/K
    g_bearing_shaft_w_k: float = 12.0
    g_bearing_headstock_w_k: float = 10.0
    g_motor_headstock_w_k: float = 20.0
    g_motor_shaft_w_k: float = 6.0
    g_headstock_column_w_k: float = 15.0
    g_column_table_w_k: float = 5.0
    # conductances to the room, W/K
    g_bearing_ambient_w_k: float = 3.0
    g_motor_ambient_w_k: float = 5.0
    g_headstock_ambient_w_k: float = 30.0
    g_shaft_ambient_w_k: float = 4.0
    g_column_ambient_w_k: float = 60.0
    g_table_ambient_w_k: float = 35.0
    # losses (n_k = rpm / 1000)
    bearing_loss_a_w: float = 6.0      # · n_k^1.5
    bearing_loss_b_w: float = 5.0      # · n_k
    motor_loss_a_w: float = 4.0        # · n_k²
    motor_loss_b_w: float = 20.0       # · n_k
    rated_power_kw: float = 15.0
    base_speed_rpm: float = 1_500.0
    motor_efficiency: float = 0.9
    # spindle cooler
    cooler_enabled: bool = True
    cooler_on_c: float = 31.0
    cooler_off_c: float = 29.0
    cooler_g_bearing_w_k: float = 10.0
    cooler_g_motor_w_k: float = 30.0
    coolant_offset_k: float = 0.0
    # growth at the tool, µm/K (and µm/K² for the nonlinearity)
    k_shaft_um_k: float = 2.7
    k_headstock_um_k: float = 0.8
    k_column_um_k: float = -8.0
    k_gradient_um_k: float = 1.5
    k_table_um_k: float = 1.0
    k_nonlinear_um_k2: float = 0.02
    # room
    ambient_mean_c: float = 20.0
    ambient_day_amplitude_k: float = 1.0
    ambient_walk_std_k: float = 0.3
    ambient_walk_tau_s: float = 3 * 3600.0
    start_hour: float = 6.0
    # sensors and integration
    sensor_noise_k: float = 0.03
    sensor_quantum_k: float = 0.1
    power_noise_kw: float = 0.01
    substep_s: float = 1.0


def _conductance_matrix(p: PlantParams, cooler_on: bool) -> tuple[np.ndarray, np.ndarray]:
    """L (symmetric, W/K) and the input matrix (W per input unit) of
    C x' = -L x + G u, u = (q_bearing, q_motor, T_amb, T_cool)."""
    links = ((_B, _S, p.g_bearing_shaft_w_k), (_B, _H, p.g_bearing_headstock_w_k),
             (_M, _H, p.g_motor_headstock_w_k), (_M, _S, p.g_motor_shaft_w_k),
             (_H, _C, p.g_headstock_column_w_k), (_C, _T, p.g_column_table_w_k))
    to_room = np.array([p.g_bearing_ambient_w_k, p.g_motor_ambient_w_k,
                        p.g_headstock_ambient_w_k, p.g_shaft_ambient_w_k,
                        p.g_column_ambient_w_k, p.g_table_ambient_w_k])
    to_cool = np.zeros(6)
    if cooler_on:
        to_cool[_B] = p.cooler_g_bearing_w_k
        to_cool[_M] = p.cooler_g_motor_w_k
    L = np.zeros((6, 6))
    for i, j, g in links:
        L[i, i] += g
        L[j, j] += g
        L[i, j] -= g
        L[j, i] -= g
    L += np.diag(to_room + to_cool)
    G = np.zeros((6, 4))
    G[_B, 0] = 1.0
    G[_M, 1] = 1.0
    G[:, 2] = to_room
    G[:, 3] = to_cool
    return L, G


def _discretise(p: PlantParams, cooler_on: bool, h_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretisation (Φ, Γ) for a sub-step of h_s seconds."""
    L, G = _conductance_matrix(p, cooler_on)
    cap = np.array([p.c_bearing_j_k, p.c_motor_j_k, p.c_headstock_j_k, p.c_shaft_j_k,
                    p.c_column_j_k, p.c_table_j_k])
    return exact_zoh(L, G, cap, h_s)


def exact_zoh(L: np.ndarray, G: np.ndarray, cap: np.ndarray, h_s: float
              ) -> tuple[np.ndarray, np.ndarray]:
    """(Φ, Γ) of C x' = -L x + G u held over h_s seconds (exact zero-order hold),
    C = diag(`cap`), L symmetric: through the symmetric C^-½ (-L) C^-½, whose
    eigenvalues are real and negative when every node reaches the room."""
    if np.any(cap <= 0.0):
        raise ValueError("heat capacities must be > 0")
    root = np.sqrt(cap)
    sym = -(L / root[:, None]) / root[None, :]       # C^-½ (-L) C^-½, symmetric
    lam, V = np.linalg.eigh(sym)
    if np.any(lam >= 0.0):
        raise ValueError("every node must be linked to the room (the network has no sink)")
    exp_l = np.exp(lam * h_s)
    left = V / root[:, None]                          # C^-½ V
    right = V.T * root[None, :]                       # Vᵀ C^½
    Phi = (left * exp_l) @ right
    # Γ = ∫0^h e^{Aτ} dτ · C⁻¹ G = C^-½ V diag((e^{λh}-1)/λ) Vᵀ C^-½ G
    Gamma = (left * ((exp_l - 1.0) / lam)) @ (V.T @ (G / root[:, None]))
    return Phi, Gamma


class ThermalPlant:
    """The machine's heat network, stepped in machine time.

    Deterministic for a seed: the same calls give the same numbers. The room
    is a function of time only (see `drivers.sim.ambient`); sensor noise is a
    separate stream.
    """

    def __init__(self, seed: int = 0, params: PlantParams | None = None) -> None:
        self.params = p = params if params is not None else PlantParams()
        if not p.substep_s > 0.0:
            raise ValueError("substep_s must be > 0")
        ambient_seq, sensor_seq = np.random.SeedSequence(seed).spawn(2)
        self.ambient = Ambient(np.random.default_rng(ambient_seq), mean_c=p.ambient_mean_c,
                               day_amplitude_k=p.ambient_day_amplitude_k,
                               start_hour=p.start_hour, walk_std_k=p.ambient_walk_std_k,
                               walk_tau_s=p.ambient_walk_tau_s)
        self._noise = np.random.default_rng(sensor_seq)
        self.time_s = 0.0
        t_amb = self.ambient(0.0)
        self._x = np.full(6, t_amb)
        self._x_ref = self._x.copy()
        self._ambient_ref = t_amb
        self._ambient_now = t_amb
        self.cooler_on = False
        self.speed_rpm = 0.0
        self.load = 0.0
        self.offset_um = 0.0
        self._cache: dict[tuple[float, bool], tuple[np.ndarray, np.ndarray]] = {}

    @property
    def rest_c(self) -> float:
        """The temperature of every node at rest (t = 0, in equilibrium with the
        room): the state in which the plant's growth is zero, the reference of a
        model of it. It is the room's at the start, seeded (the room walk)."""
        return self._ambient_ref

    # -- physics ---------------------------------------------------------
    def losses_w(self, speed_rpm: float, load: float) -> tuple[float, float, float]:
        """(q_bearing W, q_motor W, power_kw) at a speed and load fraction."""
        p = self.params
        n_k = speed_rpm / 1000.0
        q_b = p.bearing_loss_a_w * n_k ** 1.5 + p.bearing_loss_b_w * n_k
        p_cut_kw = load * p.rated_power_kw * min(1.0, speed_rpm / p.base_speed_rpm)
        q_m = (p.motor_loss_a_w * n_k * n_k + p.motor_loss_b_w * n_k
               + (1.0 / p.motor_efficiency - 1.0) * p_cut_kw * 1000.0)
        return q_b, q_m, p_cut_kw + (q_b + q_m) / 1000.0

    def _matrices(self, h_s: float) -> tuple[np.ndarray, np.ndarray]:
        key = (h_s, self.cooler_on)
        m = self._cache.get(key)
        if m is None:
            m = self._cache[key] = _discretise(self.params, self.cooler_on, h_s)
        return m

    def step(self, dt_s: float, speed_rpm: float, load: float = 0.0) -> None:
        """Advance `dt_s` seconds of machine time at a constant speed and load."""
        if not (dt_s > 0.0 and math.isfinite(dt_s)):
            raise ValueError(f"dt_s must be a positive finite number, got {dt_s!r}")
        if not 0.0 <= speed_rpm <= MAX_SPEED_RPM:
            raise ValueError(f"speed_rpm must be within 0..{MAX_SPEED_RPM:.0f}, got {speed_rpm!r}")
        if not 0.0 <= load <= 1.0:
            raise ValueError(f"load must be within 0..1, got {load!r}")
        p = self.params
        self.speed_rpm = float(speed_rpm)
        self.load = float(load)
        q_b, q_m, _ = self.losses_w(speed_rpm, load)
        n_sub = max(1, math.ceil(dt_s / p.substep_s - 1e-9))
        h = dt_s / n_sub
        u = np.array([q_b, q_m, 0.0, 0.0])
        x = self._x
        t = self.time_s
        for _ in range(n_sub):
            if p.cooler_enabled:
                if self.cooler_on and x[_B] < p.cooler_off_c:
                    self.cooler_on = False
                elif not self.cooler_on and x[_B] > p.cooler_on_c:
                    self.cooler_on = True
            t_amb = self.ambient(t + 0.5 * h)
            u[2] = t_amb
            u[3] = t_amb + p.coolant_offset_k
            Phi, Gamma = self._matrices(h)
            x = Phi @ x + Gamma @ u
            t += h
        self._x = x
        self.time_s = self.time_s + dt_s
        self._ambient_now = self.ambient(self.time_s)

    # -- observation ----------------------------------------------------
    def temperatures(self) -> dict[str, float]:
        """True node temperatures and the room, °C (no noise, no quantisation)."""
        out = {name: float(v) for name, v in zip(NODES, self._x, strict=True)}
        out["ambient"] = self._ambient_now
        return out

    def growth_um(self) -> float:
        """True Z growth at the tool, µm."""
        p = self.params
        d = self._x - self._x_ref
        d_amb = self._ambient_now - self._ambient_ref
        s = float(d[_S])
        return (p.k_shaft_um_k * s + p.k_headstock_um_k * float(d[_H])
                + p.k_column_um_k * float(d[_C])
                + p.k_gradient_um_k * (float(d[_C]) - d_amb)
                + p.k_table_um_k * float(d[_T]) + p.k_nonlinear_um_k2 * s * abs(s))

    def _quantise(self, value: float) -> float:
        q = self.params.sensor_quantum_k
        return round(round(value / q) * q, 6) if q > 0.0 else value

    def sensors(self) -> dict[str, float]:
        """What the controller shows: temperatures quantised (0.1 K) with small
        noise, speed, drive power, growth and error (growth - offset), in the
        standard names of `drivers.sim`. Each call draws fresh sensor noise."""
        p = self.params
        noise = self._noise.normal(0.0, 1.0, 6)
        out: dict[str, float] = {}
        for k, (name, idx) in enumerate(SENSOR_NODES):
            out[name] = self._quantise(float(self._x[idx]) + p.sensor_noise_k * float(noise[k]))
        out["ambient"] = self._quantise(self._ambient_now + p.sensor_noise_k * float(noise[4]))
        out["spindle_rpm"] = self.speed_rpm
        _, _, power = self.losses_w(self.speed_rpm, self.load)
        if power > 0.0:
            power = max(0.0, power + p.power_noise_kw * float(noise[5]))
        out["power_kw"] = round(power, 3)
        growth = self.growth_um()
        out["growth_um"] = growth
        out["error_um"] = growth - self.offset_um
        return out
