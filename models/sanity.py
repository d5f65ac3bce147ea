"""Physical plausibility of a compensation model (pure; no I/O).

A model can be stable and finite and still absurd: coefficients
``["1e308", "-0.9e308"]`` give a DC gain of 2e307 µm/K, a pole at
0.9999999999 (Ts = 1 s) a time constant of 317 years and 5e9 µm/K. Such a
model drives the output to ±limit and flips its sign on sensor noise, so it
is refused before it runs. Bounds (defaults no machine tool comes near; a
config may set others, `[model] max_dc_gain_um`, `max_time_constant_s`):

- |DC gain| of every term, per unit of each input channel (gain × filter DC
  gain × input coefficient): at most ``DEFAULT_MAX_DC_GAIN_UM`` = 1000 µm per
  K (or per kW, per 1000 rpm... whatever the channel's unit; a spindle grows
  some 10 µm/K, a column some 100 µm over its whole warm-up);
- the slowest time constant τ = -Ts / ln|p| of every pole p: at most
  ``DEFAULT_MAX_TIME_CONSTANT_S`` = 7 days (the slowest thermal mass of a
  machine, its bed on a foundation, settles within a day or two);
- the sample period: ``MIN_PERIOD_S`` (10 ms) ... ``MAX_PERIOD_S`` (1 h).
"""

from __future__ import annotations

import math

from models.compensation import CompensationModel, Dynamics, Term
from models.errors import ModelError
from models.greybox import GreyBox
from models.mbotv import Mbotv
from models.tf import TransferFunction

DEFAULT_MAX_DC_GAIN_UM = 1000.0
DEFAULT_MAX_TIME_CONSTANT_S = 7 * 86400.0
MIN_PERIOD_S = 0.01
MAX_PERIOD_S = 3600.0


def check_period(period_s: float, where: str) -> None:
    """ModelError unless MIN_PERIOD_S <= period_s <= MAX_PERIOD_S."""
    if not (math.isfinite(period_s) and MIN_PERIOD_S <= period_s <= MAX_PERIOD_S):
        raise ModelError(f"{where}: {period_s!r} s is outside {MIN_PERIOD_S:g} ... "
                         f"{MAX_PERIOD_S:g} s (a thermal model samples every 10 ms to 1 h)")


def pole_magnitudes(dyn: Dynamics, period_s: float) -> list[float]:
    """|p| of every pole of a term's dynamics (z-plane)."""
    if isinstance(dyn, TransferFunction):
        return [abs(p) for p in dyn.poles]
    if isinstance(dyn, GreyBox):
        rates = [dyn.p[0]] + ([dyn.p[3]] if dyn.switched else [])
        return [abs(1.0 + period_s * r) for r in rates]
    if isinstance(dyn, Mbotv):
        return [dyn.k, dyn.gamma]
    return []  # pragma: no cover - every kind is listed above


def slowest_time_constant_s(dyn: Dynamics, period_s: float) -> float:
    """τ = -Ts / ln|p| of the pole nearest the unit circle (0 without poles)."""
    mags = [m for m in pole_magnitudes(dyn, period_s) if m > 0.0]
    if not mags:
        return 0.0
    top = max(mags)
    return math.inf if top >= 1.0 else -period_s / math.log(top)


def dc_gains(term: Term) -> dict[str, float]:
    """µm per unit of each input channel at steady state (the term's gain is
    1 when it comes from a channel)."""
    gain = 1.0 if term.gain_channel else term.gain
    dc = term.dynamics.dc_gain
    return {ch: gain * dc * c for ch, c in term.inputs.items()}


def check_model(model: CompensationModel, *,
                max_dc_gain_um: float = DEFAULT_MAX_DC_GAIN_UM,
                max_time_constant_s: float = DEFAULT_MAX_TIME_CONSTANT_S) -> None:
    """ModelError naming the term and the reason when the model is absurd."""
    check_period(model.period_s, f"{model.name}.period_s")
    for term in model.terms:
        for ch, g in dc_gains(term).items():
            if not (math.isfinite(g) and abs(g) <= max_dc_gain_um):
                raise ModelError(
                    f"term {term.name!r}: DC gain {g:.4g} µm per unit of {ch} is beyond "
                    f"±{max_dc_gain_um:g} (no machine tool grows that much; check the "
                    "coefficients, or set [model] max_dc_gain_um)")
        tau = slowest_time_constant_s(term.dynamics, model.period_s)
        if not tau <= max_time_constant_s:
            raise ModelError(
                f"term {term.name!r}: slowest time constant {tau:.4g} s "
                f"({tau / 86400.0:.3g} days) is beyond {max_time_constant_s:g} s (a pole "
                "this close to 1 integrates rather than settles; check the coefficients, "
                "or set [model] max_time_constant_s)")
