"""Probes replayed offline: the daemon's own probe stage
(`compd.core.adaptation.ProbeStage`, around the estimator of `models.adaptation`)
run beside a model over a record (`compd replay --probe-every-min`), and the noise
settings a record suggests for it (`compd fit --adaptation`).

Probes: every `every_s` seconds of the record (the first at t0 + every_s), the
value of the measured column at that row, plus seeded Gaussian noise of
`noise_um` (0: the column as it is, already carrying its own measurement
noise). The stage steps once per row, its time running as the daemon's cycle
runs it (one period at the first row). At each row the adapted prediction uses
the correction known BEFORE that row's probe: the probe is the row's own
measurement, so it changes the correction of the rows after it; the daemon,
whose probe is a measuring cycle read later, applies it in the cycle that
reads it (tests/compd/offline/test_probe_replay_stage.py holds the two together).

Beside it, in the same run, the crude correction a textbook would start from:
the residual measured at each probe (probe - model) held until the next one.

Suggested settings (`suggest_settings`), from the residual r = measured -
model over a record sampled every T seconds:

- probe noise σ_v: the high-frequency part. A slow r changes little from one
  row to the next, so Var(r(k+1) - r(k)) ≈ 2σ_v²: σ_v = 1.4826·MAD(Δr)/√2
  (the median absolute deviation, robust to the few quick excursions);
- bias random walk q (µm²/s): the drift variance at the lag L = the probe
  interval: Var(r(k+L) - r(k)) ≈ 2σ_v² + q·L·T, so q = (that - 2σ_v²)/(L·T),
  floored at 0, reported as √(q·3600) µm/√h.
- the apply band (`apply_sigma`): the band holds the applied correction still
  until the estimate departs by more than 4 σ, which pays on a model at its
  noise floor (the shop machine: a residual drifting less than its noise) and
  costs on one whose error moves by more than the noise between two probes
  (the real machine of tests/data/fl_thermal: 2.7 µm per 2 h against 0.07 µm
  of noise, residue RMS 6.1 µm with the band, 4.0 without, crude 4.0). So
  0 (follow every probe) when the drift over the lag, √(q·L·T), exceeds 4 σ_v,
  else the default;
- the score's prior (`score_prior_plain_um`, `score_prior_adapted_um`): the
  RMS of the residual, and of the residual less its value τ before (τ over
  one probe spacing): what the plain model and a correction held since the
  last probe would have done on the calibration record (`score_prior_probes`),
  weighted as the number of probe spacings the records span (the evidence
  it rests on, at most 100). Always the written model's own residual, never
  the held-out blocks' (see `suggest_settings`). On the real machine holding pays at 1 h and
  2 h (ch3: 1.6 and 2.5 µm against 3.0) and loses at 4 h and 8 h (3.6 and
  4.0): the estimator there starts stood down;
- the step bound (`max_step_um`): 4 σ of the residual's change over the lag,
  √E[(r(k+L) − r(k))²], at least the default (5 µm): a bound the residual's
  own moves between probes stay within, a wrong probe's not.
Each setting written is held within the bounds `compd check` holds a model
file's [adaptation] table to (`Suggestion.bounded` says which met one).
The drift and the step bound are measured on the residue of rows
the model was not calibrated on when `compd fit` has them (its forward folds,
`suggest_settings`' `heldout`): a residual on the calibration rows themselves
understates how fast a deployed model's error moves. `compd fit
--adaptation` writes the suggestion into the model file as its `[adaptation]`
table, and the daemon and `compd replay --probe-every-min` use it unless told
otherwise.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from models.adaptation import AdaptationParams, Adapter

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


@dataclass(frozen=True)
class ProbeRun:
    """A replay with probes: the predictions with the Kalman and the crude correction."""

    adapted: FloatArray  # model + the estimator's correction at every row
    crude: FloatArray  # model + the last probe's residual, held
    rows: IntArray  # row of each probe
    values: FloatArray  # the probe values (measured column + noise)
    accepted: npt.NDArray[np.bool_]
    adapter: Adapter


def probe_rows(time_s: FloatArray, every_s: float) -> IntArray:
    """The first row at or after each multiple of `every_s` past the record's start."""
    t = time_s - time_s[0]
    marks = np.arange(every_s, float(t[-1]) + every_s * 1e-9, every_s)
    rows = np.searchsorted(t, marks - 1e-6 * every_s)
    return np.unique(rows[rows < t.size]).astype(np.int64)


def run_probes(simulated: FloatArray, measured: FloatArray, time_s: FloatArray,
               terms: FloatArray | None, *, every_s: float, noise_um: float, seed: int,
               params: AdaptationParams) -> ProbeRun:
    """Run the daemon's probe stage and the crude correction beside `simulated`
    (see the docstring). The stage (`compd.core.adaptation.ProbeStage`, applying,
    the probe measuring the displacement) steps once per row with that row's
    model output and terms; the probe taken at a row reaches it in a cycle of
    its own right after the row (no time passes), so the row's prediction is
    made before its own measurement is known."""
    from compd.core.adaptation import AdaptationSettings, ProbeReading, ProbeStage
    from compd.core.events import Event

    n_terms = 1 if terms is None else int(terms.shape[1])
    settings = AdaptationSettings("apply", "displacement", params, guard_window=0)
    stage = ProbeStage(settings, n_terms)
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(13,)))
    rows = probe_rows(time_s, every_s)
    values = measured[rows] + noise_um * rng.standard_normal(rows.size)
    accepted = np.zeros(rows.size, dtype=bool)
    adapted = np.empty_like(simulated)
    crude = np.empty_like(simulated)
    held, j = 0.0, 0
    events: list[Event] = []  # the daemon's events: the figures need none of them
    reading: ProbeReading | None = ProbeReading(math.nan, 0.0)  # the counter's baseline
    # the daemon's first cycle counts one period, as each cycle after it
    first_dt = float(time_s[1] - time_s[0]) if time_s.size > 1 else 0.0
    for k in range(simulated.size):
        model_um = float(simulated[k])
        # without gains the estimator reads no term: the output stands for the one
        row_terms = [model_um] if terms is None else terms[k].tolist()
        dt = float(time_s[k] - time_s[k - 1]) if k else first_dt
        adapted[k] = model_um + stage.step(dt, reading, complete=True, model_um=model_um,
                                           terms_um=row_terms, offset_in_force_um=None,
                                           events=events)
        reading = None
        crude[k] = model_um + held
        if j < rows.size and rows[j] == k:
            z = float(values[j])
            stage.step(0.0, ProbeReading(z, float(j + 1)), complete=True, model_um=model_um,
                       terms_um=row_terms, offset_in_force_um=None, events=events)
            accepted[j] = stage.last is not None and stage.last["accepted"] is True
            held = z - model_um
            j += 1
        events.clear()
    return ProbeRun(adapted, crude, rows, values, accepted, stage.adapter)


#: the prior's weight is the probe spacings the calibration spans, at most this many
MAX_PRIOR_PROBES = 100.0


@dataclass(frozen=True)
class Suggestion:
    probe_noise_um: float
    bias_rw_um_per_sqrt_h: float
    lag_s: float
    apply_sigma: float = AdaptationParams.apply_sigma
    max_step_um: float = AdaptationParams.max_step_um
    plain_rms_um: float = 0.0
    held_rms_um: float = 0.0
    prior_probes: float = 0.0
    #: what the drift, the step bound and the score's prior were measured on
    #: (`DRIFT_HELDOUT`, `DRIFT_CALIBRATION` or `DRIFT_PROBES`)
    drift_from: str = ""

    def as_dict(self) -> dict[str, float | str]:
        return {"probe_noise_um": self.probe_noise_um,
                "bias_rw_um_per_sqrt_h": self.bias_rw_um_per_sqrt_h, "lag_s": self.lag_s,
                "apply_sigma": self.apply_sigma, "max_step_um": self.max_step_um,
                "plain_rms_um": self.plain_rms_um, "held_rms_um": self.held_rms_um,
                "prior_probes": self.prior_probes, "drift_from": self.drift_from}

    def settings(self) -> dict[str, float]:
        """The model file's [adaptation] table (see `bounded`)."""
        return self.bounded()[0]

    def bounded(self) -> tuple[dict[str, float], dict[str, float]]:
        """The model file's [adaptation] table (`AdaptationParams` fields, rounded to four
        significant digits), each setting held within the bounds `compd check` and `run`
        hold that table to (`compd.config.schema.learnt_bounds`); and the settings that
        met a bound, each with the value the figures gave."""
        from compd.config.schema import learnt_bounds

        figures = {"bias_rw_um_per_sqrt_h": self.bias_rw_um_per_sqrt_h,
                   "probe_noise_um": self.probe_noise_um, "apply_sigma": self.apply_sigma,
                   "max_step_um": self.max_step_um, "score_prior_plain_um": self.plain_rms_um,
                   "score_prior_adapted_um": self.held_rms_um,
                   "score_prior_probes": self.prior_probes}
        bounds = learnt_bounds()
        table: dict[str, float] = {}
        hit: dict[str, float] = {}
        for name, value in figures.items():
            lo, hi = bounds[name]
            table[name] = _round(min(max(value, lo), hi))
            if not lo <= value <= hi:
                hit[name] = value
        return table, hit


def _round(v: float) -> float:
    return float(f"{v:.4g}")


#: `Suggestion.drift_from`: the residue of models calibrated without the rows it is on
DRIFT_HELDOUT = "rows the model was not calibrated on"
#: `Suggestion.drift_from`: the fitted model's residual on its own calibration rows
DRIFT_CALIBRATION = "the calibration residual"
#: `Suggestion.drift_from`: a running machine's probes (`refine_from_probes`)
DRIFT_PROBES = "the probes"
#: a held-out block gives the drift at a lag when it spans at least this many lags
MIN_BLOCK_LAGS = 2


def suggest_settings(residuals: list[FloatArray], period_s: float,
                     lag_s: float = 7200.0, heldout: Sequence[FloatArray] = ()
                     ) -> Suggestion:
    """Probe noise and bias random walk from residuals (one array per record).

    `heldout`: the residue on rows the model was not calibrated on, one array per
    contiguous block (`compd fit`'s forward folds: each block predicted by a model
    calibrated on the rows before it). The error a deployed model makes moves as it
    does there, not as the residual on its own calibration rows does: on the real
    machine of tests/data/fl_thermal (ch3, the first 20.1 h) the calibration residual
    drifts 2.9 µm/√h at 2 h, the held-out blocks 8.1, and the probes of a running
    machine said 10.1. So the drift and the step bound come from the blocks at least
    `MIN_BLOCK_LAGS` lags long, when there are any. The probe noise and the score's prior
    always come from `residuals` (the model written): the blocks' fold models, each
    calibrated on the rows before its block only, err several times more than the model
    written (the shop machine: 2.3 ... 3.8 µm RMS against 0.34 ... 0.37 on its own rows),
    and a prior measured there started the estimator applying on days where the plain
    model was better (docs/adaptation.md §3, chosen on held-out seeds)."""
    lag = max(1, round(lag_s / period_s))
    diffs = [np.diff(r) for r in residuals if r.size >= 2]
    if not diffs:
        raise ValueError("need at least two samples of residual")
    d1 = np.concatenate(diffs)
    mad = float(np.median(np.abs(d1 - np.median(d1))))
    sigma_v = 1.4826 * mad / math.sqrt(2.0)
    blocks = [np.asarray(b, dtype=np.float64) for b in heldout
              if b.size >= MIN_BLOCK_LAGS * lag + 1 and np.all(np.isfinite(b))]
    source, drift_from = (blocks, DRIFT_HELDOUT) if blocks else (residuals, DRIFT_CALIBRATION)
    far = [r[lag:] - r[:-lag] for r in source if r.size > lag]
    if not far:
        raise ValueError(f"the records are shorter than the lag of {lag * period_s:g} s")
    dl = np.concatenate(far)
    moved = float(np.mean(dl ** 2))
    q = max(0.0, (moved - 2.0 * sigma_v ** 2) / (lag * period_s))
    # the prior: what this model and a correction held over the lag did on its own
    # calibration rows (the blocks' fold models, calibrated on fewer rows, err more)
    plain, held = _held_rms(residuals, lag)
    spacings = min(sum(r.size for r in residuals) / lag, MAX_PRIOR_PROBES)
    return _suggestion(sigma_v, q, lag * period_s, moved, plain, held, spacings, drift_from)


def _suggestion(sigma_v: float, q: float, lag_s: float, moved: float, plain: float,
                held: float, spacings: float, drift_from: str) -> Suggestion:
    """The settings from the noise σ_v, the drift q (µm²/s) at the lag, the mean square
    move over the lag and the score's prior (see the module docstring)."""
    default = AdaptationParams()
    drift = math.sqrt(q * lag_s)
    apply_sigma = 0.0 if drift > default.apply_sigma * sigma_v else default.apply_sigma
    max_step = max(default.max_step_um, 4.0 * math.sqrt(moved))
    return Suggestion(sigma_v, math.sqrt(q * 3600.0), lag_s, apply_sigma, max_step,
                      plain, held, spacings, drift_from)


#: fewest usable probes (consecutive pairs + 1) a probe record must give to refine settings
MIN_REFINE_PROBES = 6
#: pairs of probes further apart than this many median spacings are not one spacing (a
#: shift's break, a restart): they are left out of the drift
MAX_SPACING_RATIO = 3.0


@dataclass(frozen=True)
class Refinement:
    """Settings refined from the probes of a running machine (`refine_from_probes`)."""

    suggestion: Suggestion
    probes: int  # probes used
    pairs: int  # consecutive pairs the drift was measured over
    spacing_s: float  # their median spacing
    noise_from: str  # "probes" (spacings varied enough to separate it) or "model file"


def refine_from_probes(time_s: npt.ArrayLike, residual_um: npt.ArrayLike,
                       probe_noise_um: float) -> Refinement:
    """Settings from probe residuals r = measured − plain model at times t (seconds,
    increasing within a run; a step back starts a new run).

    Between consecutive probes τ apart, E[(r' − r)²] = 2σ_v² + q·τ. Where the spacings
    vary by a factor 2 or more over at least 8 pairs, both are fitted (least squares,
    neither below 0); else σ_v is the model file's `probe_noise_um` and q the rest. The
    score's prior is the RMS of r (the plain model at the probes) and of r' − r (a
    correction held from one probe to the next), weighted as the pairs (at most 100):
    what this machine's probes, at this spacing, say adapting is worth. ValueError when
    there are too few probes to say anything."""
    t = np.asarray(time_s, dtype=np.float64)
    r = np.asarray(residual_um, dtype=np.float64)
    keep = np.isfinite(t) & np.isfinite(r)
    t, r = t[keep], r[keep]
    if t.size < MIN_REFINE_PROBES:
        raise ValueError(f"{t.size} usable probe(s); refining needs at least "
                         f"{MIN_REFINE_PROBES}")
    tau, dr = np.diff(t), np.diff(r)
    forward = tau > 0.0
    spacing = float(np.median(tau[forward])) if np.any(forward) else 0.0
    pair = forward & (tau <= MAX_SPACING_RATIO * spacing)
    tau, dr = tau[pair], dr[pair]
    if tau.size < MIN_REFINE_PROBES - 1:
        raise ValueError(f"{tau.size} pair(s) of consecutive probes about one spacing apart; "
                         f"refining needs at least {MIN_REFINE_PROBES - 1}")
    d2 = dr ** 2
    sigma_v, q, noise_from = probe_noise_um, 0.0, "model file"
    if tau.size >= 8 and float(tau.max()) >= 2.0 * float(tau.min()):
        a, q = _line_through(tau, d2)
        sigma_v, noise_from = math.sqrt(a / 2.0), "probes"
    else:
        q = max(0.0, (float(np.mean(d2)) - 2.0 * sigma_v ** 2) / float(np.mean(tau)))
    suggestion = _suggestion(sigma_v, q, spacing, float(np.mean(d2)),
                             math.sqrt(float(np.mean(r ** 2))), math.sqrt(float(np.mean(d2))),
                             min(float(tau.size), MAX_PRIOR_PROBES), DRIFT_PROBES)
    return Refinement(suggestion, int(t.size), int(tau.size), spacing, noise_from)


def _line_through(x: FloatArray, y: FloatArray) -> tuple[float, float]:
    """y ≈ a + q·x by least squares with a, q ≥ 0 (the better of the two one-sided fits
    where the free fit leaves the quadrant)."""
    design = np.column_stack([np.ones_like(x), x])
    (a, q), *_ = np.linalg.lstsq(design, y, rcond=None)
    if a >= 0.0 and q >= 0.0:
        return float(a), float(q)
    only_q = max(0.0, float(x @ y) / float(x @ x))
    only_a = max(0.0, float(np.mean(y)))
    if float(np.sum((y - only_q * x) ** 2)) <= float(np.sum((y - only_a) ** 2)):
        return 0.0, only_q
    return only_a, 0.0


def _held_rms(residuals: list[FloatArray], lag: int) -> tuple[float, float]:
    """RMS of the residual (the plain model's error) and of the residual less its value
    τ rows before, τ over 1 … lag (a correction held since the last probe, probes every
    lag rows at any phase), over the rows at least `lag` in."""
    taus = range(1, lag + 1, max(1, lag // 64))
    plain = [float(np.mean(r[lag:] ** 2)) for r in residuals if r.size > lag]
    held = [float(np.mean((r[lag:] - r[lag - t:r.size - t]) ** 2))
            for r in residuals if r.size > lag for t in taus]
    return math.sqrt(float(np.mean(plain))), math.sqrt(float(np.mean(held)))
