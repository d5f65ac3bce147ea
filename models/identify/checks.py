"""Checks every fitted transfer function passes before it is written.

Stability alone is not enough: a pole at |p| = 1 - 1e-12 is "stable" but its
time constant is centuries and its DC gain can be 10⁶ µm/K, a model that
drifts without bound on any record longer than the calibration. So a fitted
term is refused when

- a pole lies beyond `max_pole` (the slowest allowed time constant τ_max:
  |p| ≤ exp(-period_s / τ_max), see `models.identify.segments.pole_radius`);
- its DC gain times the span of its input over the calibration records is
  more than `MAX_DC_SPAN_RATIO` times the span of the measured displacement
  (worked number: an ambient term of 1e6 µm/K on a room that moved 6 K would
  predict 6 m where the probe saw 20 µm).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from models.diagnostics import correlation
from models.errors import ModelError
from models.sensitivity import dc_gain_sensitivity
from models.tf import TransferFunction

#: a term's steady-state response to its calibration input span may exceed
#: the measured displacement span by at most this factor
MAX_DC_SPAN_RATIO = 100.0


@dataclass(frozen=True)
class TfCheck:
    """A fitted term built exactly as the model file will hold it."""

    tf: TransferFunction
    dc_gain: float
    sensitivity: str
    poles: list[complex]


def time_constant_s(pole: complex, period_s: float) -> float:
    """-period_s / ln|p| (inf for |p| >= 1, 0 for p = 0)."""
    m = abs(pole)
    if m >= 1.0:
        return math.inf
    if m == 0.0:
        return 0.0
    return -period_s / math.log(m)


def build_checked_tf(num: Sequence[float], den: Sequence[float], name: str, *,
                     max_pole: float = 1.0, period_s: float | None = None,
                     input_span: float | None = None,
                     output_span: float | None = None) -> TfCheck:
    """Build the term's `TransferFunction` from shortest round-trip reprs (the
    model file holds these strings, so the file reproduces the floats exactly).
    Raises `ModelError` when a pole is on or outside the unit circle, beyond
    `max_pole`, or when the DC gain is absurd for the data (module docstring)."""
    tf = TransferFunction([repr(float(v)) for v in num], [repr(float(v)) for v in den],
                          name=name)
    poles = tf.poles
    slowest = max((abs(p) for p in poles), default=0.0)
    if max_pole < 1.0 and slowest > max_pole * (1.0 + 1e-12):
        per = period_s if period_s is not None else 1.0
        raise ModelError(
            f"term {name!r}: slowest pole |p| = {slowest:.9f} (time constant "
            f"{time_constant_s(slowest, per) / 86400:.3g} days) is beyond the allowed "
            f"|p| <= {max_pole:.9f} ({time_constant_s(max_pole, per) / 86400:.3g} days): the "
            "records do not determine this term's slow behaviour; record longer, or raise "
            "--max-time-constant-days if the machine really is that slow")
    dc = tf.dc_gain
    if input_span is not None and output_span is not None and output_span > 0.0:
        predicted = abs(dc) * input_span
        if not math.isfinite(dc) or predicted > MAX_DC_SPAN_RATIO * output_span:
            raise ModelError(
                f"term {name!r}: DC gain {dc:.4g} µm per input unit times the input's span "
                f"{input_span:.3g} over the records is {predicted:.3g} µm, more than "
                f"{MAX_DC_SPAN_RATIO:g}x the measured displacement span {output_span:.3g} µm: "
                "an implausible steady state (a near-integrator fitted to a slow drift); "
                "give the term another record that settles, or combine it with a "
                "channel that explains the drift")
    return TfCheck(tf=tf, dc_gain=dc, sensitivity=dc_gain_sensitivity(tf).describe(),
                   poles=poles)


#: in selection, a term's steady response to its input's calibration span may
#: exceed the displacement's span by at most this factor ("out of proportion")
PLAUSIBLE_DC_SPAN_RATIO = 4.0
#: inputs correlated at least this much whose terms have opposite-sign,
#: each larger-than-the-output steady responses cancel each other
CANCEL_R = 0.99


def implausible(nums: Sequence[Sequence[float]], dens: Sequence[Sequence[float]],
                inputs: Sequence[npt.NDArray[np.float64]], names: Sequence[str],
                output_span: float, samples: int) -> str | None:
    """Why a fitted model is one its own diagnostics reject, or None.

    `dens` holds each input's denominator (a shared one repeated). Rejected:

    - a DC gain out of proportion: |K_i| times input i's span is more than
      `PLAUSIBLE_DC_SPAN_RATIO` times the displacement's span (ch4 of the
      real record: +213 µm/K over a 3.1 K span, 660 µm, on a 58 µm output);
    - cancelling terms: two inputs correlated at |r| >= `CANCEL_R` whose
      steady responses have opposite signs and each exceed the output span
      (the model predicts the small difference of two large numbers);
    - a pole near the unit circle: a time constant longer than the records
      (|p| > exp(-1 / samples)), which the data cannot determine.
    """
    if output_span <= 0.0:
        return None
    slow = math.exp(-1.0 / max(samples, 1))
    responses: list[float] = []
    for num, den, u, name in zip(nums, dens, inputs, names, strict=True):
        a = float(np.sum(den))
        if a == 0.0:
            return f"{name}: a pole at z = 1 (an integrator)"
        pole = max((abs(p) for p in np.roots(np.asarray(den, dtype=np.float64))), default=0.0)
        if pole > slow:
            return (f"{name}: a pole |p| = {pole:.6f} near the unit circle (time constant "
                    f"longer than the {samples} samples calibrated on)")
        k = float(np.sum(num)) / a
        span = float(np.ptp(np.asarray(u, dtype=np.float64)))
        if not math.isfinite(k) or abs(k) * span > PLAUSIBLE_DC_SPAN_RATIO * output_span:
            return (f"{name}: DC gain {k:.4g} per unit over an input span {span:.3g} is "
                    f"{abs(k) * span:.3g} µm, out of proportion to the displacement's span "
                    f"{output_span:.3g} µm")
        responses.append(k)
    arrays = [np.asarray(u, dtype=np.float64) for u in inputs]
    for i in range(len(arrays)):
        for j in range(i + 1, len(arrays)):
            a_i, a_j = arrays[i], arrays[j]
            if np.std(a_i) == 0.0 or np.std(a_j) == 0.0:
                continue
            r = correlation(a_i, a_j)
            big = (abs(responses[i]) * float(np.ptp(a_i)) > output_span
                   and abs(responses[j]) * float(np.ptp(a_j)) > output_span)
            if abs(r) >= CANCEL_R and responses[i] * responses[j] * r < 0.0 and big:
                return (f"{names[i]} and {names[j]} cancel: DC gains {responses[i]:+.4g} and "
                        f"{responses[j]:+.4g} on inputs correlated at r = {r:.3f}")
    return None
