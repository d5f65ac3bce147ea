"""The probe-assisted estimator's settings (`AdaptationParams`, the daemon's
``[adaptation]`` defaults), the numerical domain each must lie in (`DOMAIN`), and what
marks a model file's settings as learnt for it (`LEARNT_KEYS`, `mark_unproven`). The
estimator itself is `models.adaptation`."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

#: The estimator's numerical domain: each setting's (low, low excluded, high). Within it
#: every quantity the filter forms stays finite (P ≤ max_total² ≤ 1e12 µm², R ≥ 1e-12 µm²),
#: so no OverflowError, ZeroDivisionError or NaN can come out of `update`. It is wider than
#: what a machine tool makes sensible (the daemon's config, `compd.config.schema`, bounds
#: each setting tighter, by its physics): 1e6 µm is a metre, 1e3 a gain of 1000×.
DOMAIN: dict[str, tuple[float, float]] = {  # (low, high); _POSITIVE ones must be > 0 too
    "bias_rw_um_per_sqrt_h": (0.0, 1e6),
    "probe_noise_um": (1e-6, 1e6),
    "gate_sigma": (0.0, 1e6),
    "max_step_um": (1e-6, 1e6),
    "max_total_um": (1e-6, 1e6),
    "gain_rw_per_sqrt_h": (0.0, 1e3),
    "max_gain": (0.0, 1e3),
    "initial_bias_sigma_um": (0.0, 1e6),
    "initial_gain_sigma": (0.0, 1e3),
    "apply_sigma": (0.0, 1e6),
    "score_window": (0.0, 1e4),
    "score_prior_plain_um": (0.0, 1e6),
    "score_prior_adapted_um": (0.0, 1e6),
    "reacquire_after": (0.0, 1e4),
    "score_prior_probes": (0.0, 1e4),
}
_POSITIVE = ("probe_noise_um", "gate_sigma", "max_step_um", "max_total_um")

@dataclass(frozen=True)
class AdaptationParams:
    """The estimator's settings (the daemon's `[adaptation]` defaults live here).

    Defaults: a probe of 0.5 µm σ (a touch probe on a reference), a bias that
    may wander 0.3 µm per √h (the best of 0.1 … 2 on the shop machine's days
    with and without a change, benchmarks/bench_adaptation.py; `compd fit
    --adaptation` estimates both from a record's residual)."""

    bias_rw_um_per_sqrt_h: float = 0.3  # process noise: bias random walk, µm/√h
    probe_noise_um: float = 0.5  # measurement noise σ of one probe, µm
    gate_sigma: float = 4.0  # innovation beyond gate_sigma·√S is refused
    max_step_um: float = 5.0  # |correction change| per accepted probe (bound)
    max_total_um: float = 20.0  # |bias| bound
    gains: bool = False  # also estimate slow per-term gain corrections
    gain_rw_per_sqrt_h: float = 0.05  # gain random walk (relative, per √h)
    max_gain: float = 0.3  # |relative gain correction| bound per term
    initial_bias_sigma_um: float = 5.0
    initial_gain_sigma: float = 0.1  # σ of each relative gain correction at start
    apply_sigma: float = 4.0  # apply the estimate only when it departs by more than this many σ
    score_window: float = 3  # accepted probes the self-score spans, whole (0: never stand down)
    score_prior_plain_um: float = 0.0  # the score's prior: the plain model's RMS error and
    score_prior_adapted_um: float = 0.0  # the held correction's, weighted as
    score_prior_probes: float = 0.0  # this many probes (0: a full score window)
    reacquire_after: float = 3  # gate refusals in a row agreeing in direction: re-acquire
    #: settings not learnt for this model (no score prior), whose worth is unknown:
    #: start stood down (the plain model), the score spanning up to `UNPROVEN_WINDOW`
    #: probes, until it shows adapting pays
    unproven: bool = False

    def __post_init__(self) -> None:
        problems = self.problems()
        if problems:
            raise ValueError("; ".join(f"{k}: {why}" for k, why in problems.items()))

    def problems(self) -> dict[str, str]:
        """Each bad field and why (empty when all are good): for a config's messages."""
        out: dict[str, str] = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name in ("gains", "unproven"):
                if not isinstance(v, bool):
                    out[f.name] = f"must be true or false, got {v!r}"
                continue
            lo, hi = DOMAIN[f.name]
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                out[f.name] = f"must be a finite number, got {v!r}"
            elif f.name in _POSITIVE and v <= 0:
                out[f.name] = f"must be > 0, got {v!r}"
            elif v < lo:
                out[f.name] = f"must be >= {lo:g}, got {v!r}"
            elif v > hi:
                out[f.name] = f"must be <= {hi:g}, got {v!r}"
        if not out and self.gains and self.max_gain <= 0:
            out["max_gain"] = "must be > 0 when gains are estimated"
        return out


#: the keys of a model file's [adaptation] table that say its settings were learnt for
#: it (`compd fit` learns them from its residual, `compd refine` from the probes): the
#: score's prior, what adapting is worth at the probe spacing
LEARNT_KEYS = ("score_prior_plain_um", "score_prior_adapted_um")


#: the accepted probes an `unproven` estimator's score spans (all its evidence, as a
#: learnt prior weighs at most this many probe spacings: compd.offline.probes)
UNPROVEN_WINDOW = 100


def mark_unproven(table: Mapping[str, Any]) -> dict[str, Any]:
    """`table` (a model file's [adaptation] settings) with `unproven` set when it holds
    no learnt prior (`LEARNT_KEYS`): settings whose worth for this model is unknown
    start stood down and earn their place from the probes."""
    if all(k in table for k in LEARNT_KEYS):
        return dict(table)
    return {**table, "unproven": True}


def with_probe_noise(table: Mapping[str, Any], probe_noise_um: float,
                     spacing_s: float = 7200.0) -> dict[str, Any]:
    """`table` (a model file's [adaptation] settings) for a probe of `probe_noise_um`
    noisier than the noise the table was learnt with (the record's rows): a correction
    held from it errs by the extra noise too, so a learnt prior's
    `score_prior_adapted_um` grows by it (√(prior² + σ_new² − σ_learnt²)); and the
    learnt band is decided again as `compd fit` decides it, with this probe's noise:
    follow every probe (`apply_sigma` 0) only where the drift over the probe spacing
    `spacing_s`, bias_rw·√(spacing in h), exceeds 4 σ of it, else the default band. A
    quieter probe leaves the table as learnt. Without a learnt prior only the noise
    changes."""
    out = {**table, "probe_noise_um": probe_noise_um}
    learnt = table.get("probe_noise_um")
    if not all(k in table for k in LEARNT_KEYS) or not isinstance(learnt, int | float):
        return out
    extra = probe_noise_um ** 2 - float(learnt) ** 2
    if extra <= 0:
        return out
    out["score_prior_adapted_um"] = math.sqrt(float(table["score_prior_adapted_um"]) ** 2
                                              + extra)
    rw = table.get("bias_rw_um_per_sqrt_h")
    if "apply_sigma" in table and isinstance(rw, int | float):
        band = AdaptationParams.apply_sigma
        drift = float(rw) * math.sqrt(spacing_s / 3600.0)
        out["apply_sigma"] = 0.0 if drift > band * probe_noise_um else band
    return out
