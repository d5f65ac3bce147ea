"""Probes replayed offline: the estimator of `models.adaptation` run beside a model
over a record (`compd replay --probe-every`), and the noise settings a record
suggests for it (`compd fit --adaptation`).

Probes: every `every_s` seconds of the record (the first at t0 + every_s), the
value of the measured column at that row, plus seeded Gaussian noise of
`noise_um` (0: the column as it is, already carrying its own measurement
noise). At each row the adapted prediction uses the correction known BEFORE
that row's probe (a probe changes the offset of the cycles after it, as in
the daemon); then the probe is weighed.

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
A residual on the calibration records themselves understates the drift a
changed machine will show: read the suggestion as a floor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from compd.offline.records import Record
from models.adaptation import AdaptationParams, Adapter
from models.compensation import CompensationModel

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


def term_contributions(model: CompensationModel, record: Record, *,
                       steady: bool = False) -> FloatArray:
    """Each term's contribution at every row (rows × terms), stepped as the daemon does."""
    samples = record.samples()
    model.reset()
    model.set_references(samples[0])
    if steady:
        model.steady_state(samples[0])
    out = np.empty((len(samples), len(model.terms)))
    for k, s in enumerate(samples):
        model.step(s)
        out[k] = model.contributions
    return out


def run_probes(simulated: FloatArray, measured: FloatArray, time_s: FloatArray,
               terms: FloatArray | None, *, every_s: float, noise_um: float, seed: int,
               params: AdaptationParams) -> ProbeRun:
    """Run the estimator and the crude correction beside `simulated` (see the docstring)."""
    n_terms = 1 if terms is None else int(terms.shape[1])
    adapter = Adapter(params, n_terms)
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(13,)))
    rows = probe_rows(time_s, every_s)
    values = measured[rows] + noise_um * rng.standard_normal(rows.size)
    accepted = np.zeros(rows.size, dtype=bool)
    adapted = np.empty_like(simulated)
    crude = np.empty_like(simulated)
    held, j = 0.0, 0
    no_terms: tuple[float, ...] = ()
    for k in range(simulated.size):
        row_terms = no_terms if terms is None else terms[k].tolist()
        if k:
            adapter.advance(float(time_s[k] - time_s[k - 1]))
        adapted[k] = simulated[k] + adapter.correction_um(row_terms)
        crude[k] = simulated[k] + held
        if j < rows.size and rows[j] == k:
            z = float(values[j])
            accepted[j] = adapter.update(z, float(simulated[k]), row_terms).accepted
            held = z - float(simulated[k])
            j += 1
    return ProbeRun(adapted, crude, rows, values, accepted, adapter)


@dataclass(frozen=True)
class Suggestion:
    probe_noise_um: float
    bias_rw_um_per_sqrt_h: float
    lag_s: float

    def as_dict(self) -> dict[str, float]:
        return {"probe_noise_um": self.probe_noise_um,
                "bias_rw_um_per_sqrt_h": self.bias_rw_um_per_sqrt_h, "lag_s": self.lag_s}


def suggest_settings(residuals: list[FloatArray], period_s: float,
                     lag_s: float = 7200.0) -> Suggestion:
    """Probe noise and bias random walk from residuals (one array per record)."""
    lag = max(1, round(lag_s / period_s))
    diffs = [np.diff(r) for r in residuals if r.size >= 2]
    if not diffs:
        raise ValueError("need at least two samples of residual")
    d1 = np.concatenate(diffs)
    mad = float(np.median(np.abs(d1 - np.median(d1))))
    sigma_v = 1.4826 * mad / math.sqrt(2.0)
    far = [r[lag:] - r[:-lag] for r in residuals if r.size > lag]
    if not far:
        raise ValueError(f"the records are shorter than the lag of {lag * period_s:g} s")
    dl = np.concatenate(far)
    q = max(0.0, (float(np.mean(dl ** 2)) - 2.0 * sigma_v ** 2) / (lag * period_s))
    return Suggestion(sigma_v, math.sqrt(q * 3600.0), lag * period_s)
