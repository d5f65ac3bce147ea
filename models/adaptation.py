"""Probe-assisted adaptation: a bounded Kalman filter on the model's output error.

A calibrated model drifts away from the machine (sensors age, the room and the
coolant change, a heat source grows). A touch probe or tool setter measures
the real thermal displacement now and then; this estimator learns from those
measurements what the model misses, as a correction ADDED to the model output:

    adapted(k) = model(k) + b(k) + Σ_i g_i(k) · term_i(k)

State x = [b, g_1 … g_n]: an output bias b (µm) and, optionally (`gains`),
a slow relative correction g_i of each term's gain (term_i = the term's
contribution, `CompensationModel.contributions`). Each is a random walk:

    process:      x(t + dt) = x(t) + w,  Var w = diag(q_b, q_g … q_g) · dt
                  q_b = bias_rw_um_per_sqrt_h² / 3600 s   (µm²/s)
                  q_g = gain_rw_per_sqrt_h² / 3600 s      (1/s)
    measurement:  z = model + H·x + v,   H = [1, term_1 … term_n],  Var v = R = probe_noise_um²

A probe z gives the innovation y = z − (model + H·x) and its variance
S = H P Hᵀ + R. Then, in this order:

1. gate: |y| > gate_sigma · √S is refused ("gate": a chip under the probe,
   a wrong tool) and never learnt; a non-finite input is refused ("fault");
2. the Kalman gain K = P Hᵀ / S is scaled by α ∈ (0, 1] so that the change
   of the correction at this probe, |H·Δx|, and of the bias, |Δb|, stay within
   `max_step_um` (a suboptimal gain, which the Joseph form below keeps exact).
   A precise probe (R < `PRECISE_PROBE` · S: its noise under 2 % of what the
   filter is unsure of) is taken whole before that scaling: K = P Hᵀ / (H P Hᵀ),
   so that the prediction meets the probe (H K = 1, the residual at the probe
   held, as the crude correction does). The optimal gain there differs from 1
   by less than 2 %, which under the random-walk model buys < 0.05 % of
   variance; a real machine's error drifts the same way for hours, and a gain
   of 0.98 leaves 2 % of each probe's step behind (on the real record's 1 h
   probes that cost 0.4–0.6 % of residue RMS against holding the last residual);
3. x += α K y, then the bias is held within ±`max_total_um` and each gain
   within ±`max_gain` (a box; should that clipping change |H·Δx| beyond
   the step bound, the whole step is shrunk along the segment, which stays
   in the box). The covariance is not changed by the clipping;
4. Joseph form: P = (I − K'H) P (I − K'H)ᵀ + K' R K'ᵀ with K' = α K, then
   symmetrised: it stays symmetric positive semi-definite for any K'.

Time update (`advance`) is lazy: it only adds dt to a pending interval (one
float addition per sample); the interval's Q is added to P before a probe is
weighed, when a σ is read and on export. The bias variance is capped at
`max_total_um²` and each gain's at `max_gain²` (larger uncertainties mean
nothing once the state is bounded; capping by a diagonal congruence keeps P
positive). `correction_um` is one attribute read without gains and an
n-term dot product with them: no allocation either way.

The correction APPLIED is earned (`apply_sigma`, default 4): the filter's
estimate x moves with every accepted probe, but the applied state x_a (what
`correction_um` adds) moves to it only when the estimate departs from it
significantly at the probe's operating point,

    |H·(x − x_a)| > apply_sigma · √(H P Hᵀ)    (P after the update)

and then only by the part beyond that band (a soft threshold, like the play
of a backlash: x_a += (x − x_a)·(1 − band/|H·(x − x_a)|)), at most
`max_step_um` (|H·Δx_a| and |Δb_a|). Moving all the way to the estimate
overshot: the estimate that crosses the band is the noisiest one, and the
applied correction then stayed off when the estimate came back inside the
band (0.63 of plain on a day without change). Why the band: a constant
correction costs no range, a varying one does. A model at its noise floor
sees only noise and slow excursions of its own residual in the probes; a
correction following them moves the residual's extremes (on the shop
machine's days without change the always-following filter lost up to 18 %
of the plain range reduction, 0.82 of plain). With the test the applied
correction stays put until the probes show a real mismatch
(benchmarks/bench_adaptation.py, docs/adaptation.md §5). apply_sigma = 0
applies every accepted probe's estimate (the filter as it is).

Numerical domain (`DOMAIN`, `MAX_INPUT_UM`): every setting has a finite range
(wider than a machine tool makes sensible; the daemon's config bounds them by
their physics) and a probe value, model output or term beyond ±1 m is refused
("fault"). Within it every product the filter forms is finite: no
OverflowError, no NaN, for any finite input to `update` or any restored state.

The estimator keeps score of itself (`score_window`, default 3): at each
accepted probe, the squared error of the plain model (z − model) and of the
adapted prediction the machine had (z − model − the applied correction before
the probe), over the last `score_window` accepted probes. While the adapted
sum is larger than the plain one, adapting does not pay and the estimator
STANDS DOWN: `correction_um` returns 0 (the plain model), the filter keeps
learning, and the score goes on counting what the adapted prediction would
have been, so that it takes over again as soon as that pays. `stand_downs`
counts the times it stood down; `score_window = 0` never stands down.
Standing down and taking over again move the whole correction at once:
`max_step_um` does not bound them (the daemon's output stage, its slew, does).
Settings not learnt for the model (`unproven`: the daemon and `compd replay` set
it when the model file's [adaptation] table holds no score prior) start stood
down too, and their score spans up to `UNPROVEN_WINDOW` accepted probes (all the
evidence there is, where a learnt prior would weigh in): the library's defaults
lagged a real machine's drift and made it worse than the plain model
(docs/adaptation.md §6; a window of 3 took over on three good probes and lost
the next two), so they must earn their place from the probes first. The score
may start from a prior (`score_prior_plain_um`,
`score_prior_adapted_um`: the RMS error of the plain model and of a correction
held over one probe spacing, on the calibration record: `compd fit
--adaptation` learns them), weighted as `score_prior_probes` probes (the
probe spacings the calibration record spans; 0: a full window; the window
then spans at least as many probes); a prior that
says adapting does not pay at this probe spacing starts the estimator stood
down, until the probes show otherwise.

A real, sudden change larger than the gate is refused like an outlier at
first. But `reacquire_after` (default 3) gate refusals in a row that agree in
direction are evidence, not noise (a chip under the probe does not repeat the
same way): at the last of them the estimator RE-ACQUIRES. The bias variance
is inflated to that probe's innovation² (at most max_total_um²), and the
probe is weighed without the gate and without the step bound on the estimate
(re-baselined: the estimate jumps most of the way), the box held; the applied
correction then follows it by at most `max_step_um` per probe (and in the
daemon through the output stage's clamp and slew). Only a change the
correction may hold is re-acquired: when the bias it asks for is beyond
±max_total_um (a probe 500 µm off is no thermal drift), the refusals go on
and recalibration is the answer. `reacquisitions` counts them; 0 never
re-acquires.

Worked number: bias only, P = 4 µm² (σ 2 µm), R = 0.25 µm² (σ 0.5 µm), a
first probe 3 µm above the model: S = 4.25, K = 0.941, b = 2.824 µm,
σ_b = 0.485 µm; 2.824 > 4 · 0.485 = 1.940, so 2.824 − 1.940 = 0.883 µm is
applied. A probe 50 µm off (|y| = 50 > 4·√4.25 = 8.2) is refused. With
P = 25 µm² (σ 5 µm) the same probe is precise (R/S = 0.0099 < 0.02): K = 1,
b = 3.000 µm, σ_b = 0.5 µm.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from models.adaptation_params import (
    DOMAIN,
    LEARNT_KEYS,
    UNPROVEN_WINDOW,
    AdaptationParams,
    mark_unproven,
    with_probe_noise,
)

__all__ = ["DOMAIN", "LEARNT_KEYS", "MAX_INPUT_UM", "PRECISE_PROBE", "STATE_VERSION",
           "UNPROVEN_WINDOW", "AdaptationParams", "Adapter", "ProbeOutcome", "mark_unproven",
           "with_probe_noise"]

FloatArray = npt.NDArray[np.float64]

#: version of `Adapter.export_state`'s layout
STATE_VERSION = 3
#: layouts `Adapter.from_state` reads (version 1 had no applied state: it was x; versions 1
#: and 2 had no score: they start with an empty one)
_READABLE_VERSIONS = (1, 2, 3)
_SECONDS_PER_HOUR = 3600.0

#: a probe value, model output or term beyond ±1 m is no thermal displacement: refused
#: ("fault"), never weighed (and the products the filter forms stay finite)
MAX_INPUT_UM = 1e6
#: a probe whose noise variance is below this share of the innovation variance S is
#: taken whole (H·K = 1; module docstring, step 2)
PRECISE_PROBE = 0.02
#: the pending random walk is counted up to ~32,000 years (the variance is capped long before)
_MAX_PENDING_S = 1e12


@dataclass(frozen=True)
class ProbeOutcome:
    """What one probe did: accepted (learnt) or refused, and why."""

    accepted: bool
    reason: str | None  # None if accepted; "gate" (innovation too large), "fault", …
    innovation_um: float  # measured - the filter's prediction (model + H·x, before the update)
    innovation_sigma_um: float  # √S
    bias_um: float  # the applied bias after the probe (what correction_um adds)
    bias_sigma_um: float  # σ of the filter's bias estimate
    applied: bool = False  # the applied correction moved at this probe (the apply_sigma test)
    estimated_bias_um: float = math.nan  # the filter's bias estimate after the probe
    standing_down: bool = False  # after the probe, the score says adapting does not pay
    reacquired: bool = False  # this probe re-acquired after refusals agreeing in direction


class Adapter:
    """One estimator per model; see the module docstring for the equations."""

    def __init__(self, params: AdaptationParams, n_terms: int) -> None:
        if isinstance(n_terms, bool) or not isinstance(n_terms, int) or n_terms < 1:
            raise ValueError(f"n_terms: must be an integer >= 1, got {n_terms!r}")
        self.params = params
        self.n_terms = n_terms
        n = 1 + (n_terms if params.gains else 0)
        self._x: FloatArray = np.zeros(n)
        self._cap: FloatArray = np.array(
            [_sq(params.max_total_um)] + [_sq(params.max_gain)] * (n - 1))
        self._p: FloatArray = np.diag(np.minimum(
            [_sq(params.initial_bias_sigma_um)] + [_sq(params.initial_gain_sigma)] * (n - 1),
            self._cap))
        self._q: FloatArray = np.array(
            [_sq(params.bias_rw_um_per_sqrt_h) / _SECONDS_PER_HOUR]
            + [_sq(params.gain_rw_per_sqrt_h) / _SECONDS_PER_HOUR] * (n - 1))
        self._xa: FloatArray = np.zeros(n)  # the applied state (see apply_sigma)
        self._pending_s = 0.0
        self.accepted = 0
        self.refused = 0
        self.applied_moves = 0  # probes at which the applied correction moved
        self._bias = 0.0
        self._gains: list[float] = [0.0] * (n - 1)
        #: (plain², adapted²) at each of the last score_window accepted probes
        self._score: list[tuple[float, float]] = []
        #: a prior that says adapting does not pay starts stood down (until probes say it
        #: does), and so do settings whose worth is unknown (`unproven`)
        self._standing_down = params.score_window >= 1 and (
            params.unproven
            or params.score_prior_adapted_um > params.score_prior_plain_um)
        self.stand_downs = 0  # times the score made the estimator stand down
        #: gate refusals in a row agreeing in direction (signed: + above, - below)
        self._streak = 0
        self.reacquisitions = 0

    # -- per sample (cheap) --------------------------------------------------------------------

    def correction_um(self, terms_um: Sequence[float]) -> float:
        """What to add to the model output: b + Σ g_i·term_i (terms ignored without gains);
        0 while the estimator stands down (its score says adapting does not pay)."""
        if self._standing_down:
            return 0.0
        c = self._bias
        if self._gains:
            for g, t in zip(self._gains, terms_um, strict=True):
                c += g * t
        return c

    def advance(self, dt_s: float) -> None:
        """Let dt_s seconds pass (lazy: Q is added to P when it is next needed)."""
        if not 0.0 <= dt_s < math.inf:
            raise ValueError(f"dt_s: must be a finite duration >= 0 s, got {dt_s!r}")
        self._pending_s += dt_s  # capped where it is used (one addition per sample)

    # -- reading -------------------------------------------------------------------------------

    @property
    def bias_um(self) -> float:
        """The applied bias (what `correction_um` adds, besides the gains' part)."""
        return self._bias

    @property
    def standing_down(self) -> bool:
        """The score says adapting does not pay: the correction is 0 (see the module)."""
        return self._standing_down

    @property
    def score_um(self) -> tuple[float, float]:
        """RMS of the plain model's and of the adapted prediction's error over the score's
        window of accepted probes (µm; NaN before the first)."""
        if not self._score:
            return math.nan, math.nan
        n = len(self._score)
        return (math.sqrt(sum(p for p, _ in self._score) / n),
                math.sqrt(sum(a for _, a in self._score) / n))

    @property
    def gain_corrections(self) -> tuple[float, ...]:
        """Each term's applied relative gain correction g_i (empty without gains)."""
        return tuple(self._gains)

    @property
    def estimated_bias_um(self) -> float:
        """The filter's bias estimate (applied once it departs significantly)."""
        return float(self._x[0])

    @property
    def estimated_gains(self) -> tuple[float, ...]:
        """The filter's gain estimates (empty without gains)."""
        return tuple(float(g) for g in self._x[1:])

    @property
    def bias_sigma_um(self) -> float:
        """σ of the bias now (the pending random walk included)."""
        return math.sqrt(max(0.0, float(self._covariance()[0, 0])))

    def covariance(self) -> FloatArray:
        """A copy of P now (the pending random walk included)."""
        return self._covariance().copy()

    def _covariance(self) -> FloatArray:
        if self._pending_s == 0.0:
            return self._p
        p = self._p + np.diag(self._q * min(self._pending_s, _MAX_PENDING_S))
        d = np.diag(p)
        over = d > self._cap
        if np.any(over):
            s = np.ones_like(d)
            s[over] = np.sqrt(self._cap[over] / d[over])  # d > cap >= 0 there
            p = p * np.outer(s, s)
        return (p + p.T) * 0.5

    def _h(self, terms_um: Sequence[float]) -> FloatArray:
        if not self._gains:
            return np.ones(1)
        if len(terms_um) != self.n_terms:
            raise ValueError(f"terms_um: expected {self.n_terms} terms, got {len(terms_um)}")
        return np.concatenate(([1.0], np.asarray(terms_um, dtype=np.float64)))

    # -- probes --------------------------------------------------------------------------------

    def update(self, measured_um: float, model_um: float,
               terms_um: Sequence[float]) -> ProbeOutcome:
        """Weigh one probe: gate, bounded step, Joseph-form covariance update."""
        h = self._h(terms_um)
        if not (_physical(measured_um) and _physical(model_um)
                and bool(np.all(np.abs(h) <= MAX_INPUT_UM))):  # NaN compares False
            return self.refuse("fault", measured_um, model_um, terms_um)
        p = self._covariance()
        r = _sq(self.params.probe_noise_um)
        y = measured_um - (model_um + float(h @ self._x))
        ph = p @ h
        s = float(h @ ph) + r
        if abs(y) > self.params.gate_sigma * math.sqrt(s):
            return self._refuse_or_reacquire(measured_um, model_um, terms_um, h, y, p, r)
        self._streak = 0
        self._score_probe(measured_um, model_um, h)
        k = ph / (s - r) if r < PRECISE_PROBE * s else ph / s
        dx = k * y
        alpha = self._step_scale(h, dx)
        k = k * alpha
        self._x = self._bounded(self._x, self._x + k * y, h)
        moved = self._weighed(p, k, h, r)
        return ProbeOutcome(True, None, y, math.sqrt(s), self._bias, self.bias_sigma_um,
                            moved, float(self._x[0]), self._standing_down)

    def _refuse_or_reacquire(self, measured_um: float, model_um: float,
                             terms_um: Sequence[float], h: FloatArray, y: float,
                             p: FloatArray, r: float) -> ProbeOutcome:
        """A gate refusal, or at the reacquire_after-th agreeing one a re-acquisition."""
        sign = 1 if y > 0 else -1
        self._streak = self._streak + sign if self._streak * sign > 0 else sign
        n = int(self.params.reacquire_after)
        holdable = abs(float(self._x[0]) + y) <= self.params.max_total_um
        if n < 1 or abs(self._streak) < n or not holdable:
            # the filter does not trust it, but the probe measured what the applied
            # correction did: the score weighs it (one outlier is within the window's
            # scatter; refusals that agree are not, and a correction they leave stale
            # in the wrong direction stands down)
            self._score_probe(measured_um, model_um, h)
            if n >= 1 and abs(self._streak) >= n and not self._standing_down:
                # a change beyond what the correction may hold: the applied correction
                # is stale, whatever the score says yet; the plain model until it is not
                self._standing_down = True
                self.stand_downs += 1
            return self.refuse("gate", measured_um, model_um, terms_um)
        # re-acquire: inflate the bias variance, weigh the probe ungated and unbounded
        self._streak = 0
        p = p.copy()
        p[0, 0] = min(float(self._cap[0]), max(float(p[0, 0]), _sq(y)))
        self._score_probe(measured_um, model_um, h)
        ph = p @ h
        s = float(h @ ph) + r
        k = ph / s
        box = np.sqrt(self._cap)
        self._x = np.clip(self._x + k * y, -box, box)
        moved = self._weighed(p, k, h, r)
        self.reacquisitions += 1
        return ProbeOutcome(True, None, y, math.sqrt(s), self._bias, self.bias_sigma_um,
                            moved, float(self._x[0]), self._standing_down, True)

    def _weighed(self, p: FloatArray, k: FloatArray, h: FloatArray, r: float) -> bool:
        """After the estimate took a probe with gain k: the Joseph-form covariance, the
        applied state moved if the estimate departs enough; whether it moved."""
        a = np.eye(len(h)) - np.outer(k, h)
        p = a @ p @ a.T + r * np.outer(k, k)
        self._p = (p + p.T) * 0.5
        self._pending_s = 0.0
        self.accepted += 1
        return self._apply_if_significant(h)

    def _score_probe(self, measured_um: float, model_um: float, h: FloatArray) -> None:
        """Score a probe: the plain model's error and the applied correction's."""
        self._keep_score(measured_um - model_um,
                         measured_um - model_um - float(h @ self._xa))

    def _keep_score(self, plain_um: float, adapted_um: float) -> None:
        """Score one accepted probe; stand down while adapting loses over the window."""
        window = _score_window(self.params)
        if window <= 0:
            return
        self._score.append((_sq(plain_um), _sq(adapted_um)))
        del self._score[:-window]
        down = _score_verdict(self._score, self.params, self._standing_down)
        if down and not self._standing_down:
            self.stand_downs += 1
        self._standing_down = down

    def _apply_if_significant(self, h: FloatArray) -> bool:
        """Move the applied state to the estimate when it departs by > apply_sigma σ."""
        d = self._x - self._xa
        if not np.any(d):
            return False
        change = abs(float(h @ d))
        limit = self.params.apply_sigma * math.sqrt(max(0.0, float(h @ self._p @ h)))
        if self.params.apply_sigma > 0:
            if change <= limit:
                return False
            d = d * (1.0 - limit / change)  # only the part beyond the band (soft threshold)
        self._set_applied(self._xa + d * self._step_scale(h, d))
        self.applied_moves += 1
        return True

    def _step_scale(self, h: FloatArray, dx: FloatArray) -> float:
        """α ≤ 1 so that |H·α·dx| and |α·dx_b| stay within max_step_um."""
        lim = self.params.max_step_um
        biggest = max(abs(float(h @ dx)), abs(float(dx[0])))
        return 1.0 if biggest <= lim else lim / biggest

    def _bounded(self, old: FloatArray, new: FloatArray, h: FloatArray) -> FloatArray:
        """`new` held in the box (bias ±max_total_um, gains ±max_gain), the step bound kept."""
        box = np.sqrt(self._cap)
        new = np.clip(new, -box, box)
        change = abs(float(h @ (new - old)))
        lim = self.params.max_step_um
        if change > lim:  # clipping undid a cancellation: shrink the step (the box is convex)
            new = old + (new - old) * (lim / change)
        return new

    def _set_applied(self, xa: FloatArray) -> None:
        self._xa = xa
        self._bias = float(xa[0])
        self._gains = [float(g) for g in xa[1:]]

    def refuse(self, reason: str, measured_um: float, model_um: float,
               terms_um: Sequence[float]) -> ProbeOutcome:
        """Record a probe not used (counted; the state is unchanged)."""
        self.refused += 1
        y, sigma = math.nan, math.nan
        try:
            h = self._h(terms_um)
        except ValueError:
            h = np.full(len(self._x), math.nan)
        if _physical(measured_um) and _physical(model_um) \
                and bool(np.all(np.abs(h) <= MAX_INPUT_UM)):
            y = measured_um - (model_um + float(h @ self._x))
            sigma = math.sqrt(max(0.0, float(h @ self._covariance() @ h))
                              + _sq(self.params.probe_noise_um))
        return ProbeOutcome(False, reason, y, sigma, self._bias, self.bias_sigma_um,
                            False, float(self._x[0]), self._standing_down)

    # -- checkpoint ----------------------------------------------------------------------------

    def export_state(self) -> dict[str, Any]:
        """JSON-able state: floats, lists of floats and the integers n_terms and counters."""
        return {
            "version": STATE_VERSION,
            "n_terms": self.n_terms,
            "gains": bool(self._gains),
            "x": [float(v) for v in self._x],
            "applied": [float(v) for v in self._xa],
            "P": [[float(v) for v in row] for row in self._p],
            "pending_s": min(self._pending_s, _MAX_PENDING_S),
            "accepted": self.accepted,
            "refused": self.refused,
            "applied_moves": self.applied_moves,
            "score": [[p, a] for p, a in self._score],
            "standing_down": self._standing_down,
            "stand_downs": self.stand_downs,
            "streak": self._streak,
            "reacquisitions": self.reacquisitions,
        }

    @classmethod
    def from_state(cls, params: AdaptationParams, n_terms: int,
                   state: Mapping[str, Any]) -> Adapter:
        """An estimator resumed from `export_state`; ValueError naming what is wrong."""
        out = cls(params, n_terms)
        if not isinstance(state, Mapping):
            raise ValueError("adaptation state: must be a table")
        version = state.get("version")
        if isinstance(version, bool) or version not in _READABLE_VERSIONS:
            raise ValueError(f"adaptation state: version {version!r}, "
                             f"expected one of {_READABLE_VERSIONS}")
        if state.get("n_terms") != n_terms or state.get("gains") is not params.gains:
            raise ValueError(f"adaptation state: made for {state.get('n_terms')!r} terms "
                             f"(gains {state.get('gains')!r}), not {n_terms} (gains "
                             f"{params.gains})")
        n = len(out._x)
        x = _floats(state.get("x"), "x", (n,))
        xa = x if version == 1 else _floats(state.get("applied"), "applied", (n,))
        p = _floats(state.get("P"), "P", (n, n))
        pending = _floats(state.get("pending_s"), "pending_s", ())
        if float(np.max(np.abs(p))) > float(np.max(out._cap)) * (1 + 1e-9):
            raise ValueError("adaptation state: P beyond the variances the settings allow")
        _check_covariance(p)
        box = np.sqrt(out._cap)
        if (np.any(np.abs(x) > box * (1 + 1e-12)) or np.any(np.abs(xa) > box * (1 + 1e-12))
                or not 0.0 <= float(pending) <= _MAX_PENDING_S):
            raise ValueError("adaptation state: x or applied beyond its bounds or pending_s "
                             f"not within 0 ... {_MAX_PENDING_S:g} s")
        # P within its caps (the off-diagonals by Cauchy-Schwarz): every product the
        # filter forms from it stays finite
        if np.any(np.abs(p) > np.sqrt(np.outer(out._cap, out._cap)) * (1 + 1e-9)):
            raise ValueError("adaptation state: P beyond the variances the settings allow")
        counts = [state.get("accepted"), state.get("refused"), state.get("applied_moves", 0),
                  state.get("stand_downs", 0), state.get("reacquisitions", 0)]
        if any(isinstance(c, bool) or not isinstance(c, int) or c < 0 for c in counts):
            raise ValueError("adaptation state: accepted/refused/applied_moves/stand_downs/"
                             "reacquisitions must be integers >= 0")
        streak = state.get("streak", 0)
        if isinstance(streak, bool) or not isinstance(streak, int) or abs(streak) > 1e4:
            raise ValueError("adaptation state: streak must be an integer within ±10000")
        raw_score = state.get("score", []) if version >= 3 else []
        if not isinstance(raw_score, list):
            raise ValueError("adaptation state: score must be a list of [plain², adapted²]")
        score = _floats(raw_score, "score", (len(raw_score), 2)) if raw_score \
            else np.zeros((0, 2))
        down = state.get("standing_down", False) if version >= 3 else False
        if not isinstance(down, bool) or np.any(score < 0) \
                or np.any(score > _sq(2 * MAX_INPUT_UM)):
            raise ValueError("adaptation state: score must be squared errors within the "
                             "domain, standing_down true or false")
        out._p = p
        out._pending_s = float(pending)
        out._x = x
        out._set_applied(xa)
        (out.accepted, out.refused, out.applied_moves, out.stand_downs,
         out.reacquisitions) = (int(c) for c in counts)
        out._streak = int(streak)
        window = _score_window(params)
        out._score = [(float(p), float(a)) for p, a in score][-window:] if window else []
        out._standing_down = down and window > 0
        return out


def _score_verdict(score: Sequence[tuple[float, float]], params: AdaptationParams,
                   down: bool) -> bool:
    """Stand down? The paired difference adapted² − plain² per scored probe, with the prior
    as `score_prior_probes` probes of its own difference, decides: its mean beyond one
    standard error of that mean (the window's scatter) moves the estimator to the side it
    favours; within it, the estimator stays where it is. A few probes that scatter about
    a tie do not switch adaptation off and on; a window that agrees does (a difference
    without scatter is evidence at any size)."""
    d = [a - p for p, a in score]
    weight = params.score_prior_probes or len(score)
    prior = _sq(params.score_prior_adapted_um) - _sq(params.score_prior_plain_um)
    mean = (sum(d) + weight * prior) / (len(d) + weight)
    if len(d) < 2:  # no scatter to weigh it by yet: the sign decides (a tie: no change)
        return mean > 0.0 or (mean == 0.0 and down)
    centre = sum(d) / len(d)
    spread = math.sqrt(sum((x - centre) ** 2 for x in d) / (len(d) - 1) / len(d))
    if mean > spread:
        return True
    if mean < -spread:
        return False
    return down


def _score_window(params: AdaptationParams) -> int:
    """The probes the score spans: score_window, and with a prior at least as many as the
    prior weighs (its evidence and the probes' weigh alike); 0 when score_window is 0."""
    window = int(params.score_window)
    if window <= 0:
        return 0
    return max(window, int(params.score_prior_probes), UNPROVEN_WINDOW if params.unproven else 0)


def _sq(v: float) -> float:
    """v² as a float product (inf beyond the float range, where ** raises OverflowError)."""
    return v * v


def _physical(v: float) -> bool:
    """Finite and within ±MAX_INPUT_UM (NaN is not)."""
    return -MAX_INPUT_UM <= v <= MAX_INPUT_UM


def _numbers_only(value: Any) -> bool:
    if isinstance(value, list | tuple):
        return all(_numbers_only(v) for v in value)
    return isinstance(value, int | float) and not isinstance(value, bool)


def _floats(value: Any, key: str, shape: tuple[int, ...]) -> FloatArray:
    if not _numbers_only(value):
        raise ValueError(f"adaptation state: {key} must be numbers")
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"adaptation state: {key} must be numbers") from None
    if arr.shape != shape or not np.all(np.isfinite(arr)):
        raise ValueError(f"adaptation state: {key} must be finite numbers of shape {shape}")
    return arr


def _check_covariance(p: FloatArray) -> None:
    if not np.allclose(p, p.T, rtol=1e-9, atol=1e-12):
        raise ValueError("adaptation state: P is not symmetric")
    top = max(1.0, float(np.max(np.abs(p))))  # scaled: eigvalsh of 1e300s overflows
    if float(np.min(np.linalg.eigvalsh(p / top))) < -1e-9:
        raise ValueError("adaptation state: P is not positive semi-definite")
