"""A compensation model described as plain data and checked for plausibility.

`describe_model` gives each term's poles, zeros, stability, DC gain (with its
unit) and the DC gain's sensitivity to the printed digits: what `compd check`
prints (text or --json), `compd check CONFIG` summarises and `compd report`
tabulates. `plausibility` lists what is stable yet implausible (cancelling DC
gains, a DC gain out of proportion, an alternating pole); `compd check` warns
of it and `compd fit` refuses it. The text helpers say a pole and a duration
the way a person reads them.
"""

from __future__ import annotations

import math
from typing import Any

#: without a recorded range, a temperature term's DC gain above this (µm/K) is
#: out of proportion for a machine tool (steel grows 11.5 µm per metre and kelvin)
MAX_PLAUSIBLE_UM_PER_K = 50.0

def _pair(z: complex) -> list[float]:
    return [z.real, z.imag]


def _finite(x: float) -> float | None:
    return x if math.isfinite(x) else None


def describe_model(model: Any) -> dict[str, Any]:
    """Per-term analysis as plain data (the --json shape)."""
    from models.greybox import GreyBox
    from models.mbotv import Mbotv
    from models.sensitivity import dc_gain_sensitivity
    from models.tf import TransferFunction

    terms: list[dict[str, Any]] = []
    for t in model.terms:
        dyn = t.dynamics
        unit = dc_gain_unit(t)
        entry: dict[str, Any] = {"name": t.name, "inputs": dict(t.inputs),
                                 "gain": t.gain_channel or t.gain, "dc_gain_unit": unit}
        if isinstance(dyn, TransferFunction):
            sens = dc_gain_sensitivity(dyn)
            entry.update(
                kind="tf", order=dyn.order,
                poles=[_pair(p) for p in dyn.poles], zeros=[_pair(z) for z in dyn.zeros],
                stable=dyn.is_stable, cancelled_unit_circle=list(dyn.cancelled),
                dc_gain=dyn.dc_gain, dc_gain_sensitivity=_finite(sens.first_order),
                dc_gain_range=[sens.low, sens.high] if sens.bounded else None,
                dc_gain_well_determined=sens.well_determined,
                dc_gain_note=sens.describe(unit))
        elif isinstance(dyn, GreyBox):
            poles = [1.0 + dyn.period_s * dyn.p[0]] + (
                [1.0 + dyn.period_s * dyn.p[3]] if dyn.switched else [])
            entry.update(kind="greybox", poles=[[p, 0.0] for p in poles], zeros=[],
                         stable=True, dc_gain=dyn.dc_gain, dc_gain_sensitivity=None)
        elif isinstance(dyn, Mbotv):
            entry.update(kind="mbotv", poles=[[dyn.k, 0.0], [dyn.gamma, 0.0]], zeros=[],
                         stable=True, dc_gain=dyn.dc_gain, dc_gain_sensitivity=None)
        terms.append(entry)
    out: dict[str, Any] = {"model": model.name, "period_s": model.period_s, "terms": terms}
    if model.fallbacks:
        out["fallbacks"] = {lost: {**describe_model(fb),
                                   "validation_fit_percent":
                                       fb.provenance.get("validation_fit_percent")}
                            for lost, fb in sorted(model.fallbacks.items())}
    return out


def dc_gain_unit(term: Any) -> str:
    """The unit of a term's DC gain: µm per kelvin for a temperature term
    (relative to its reference), else µm per unit of its input (µm/rpm for a
    spindle speed, µm/kW for a drive power); a gain channel multiplies it."""
    from compd.offline.channel_kind import step_unit

    per = step_unit(term.inputs, term.relative)
    gain = f"·{term.gain_channel}" if term.gain_channel else ""
    return f"µm/({per}{gain})" if gain else f"µm/{per}"


#: a negative real pole of smaller magnitude is no behaviour to warn of: its mode
#: alternates sign every sample but shrinks by this factor or more each sample
#: (below 1 % of its start after two), gone before the slew limit lets it show
NEGLIGIBLE_ALTERNATING = 0.1


def plausibility(model: Any) -> list[str]:
    """Warnings about a model that is stable yet implausible: DC gains that
    cancel, a DC gain out of proportion to the recorded range (the spans
    `compd fit` writes into the provenance; else a fixed bound per kelvin),
    negative real poles (a mode that alternates sign every sample) of magnitude
    `NEGLIGIBLE_ALTERNATING` or more."""
    from models.identify.checks import PLAUSIBLE_DC_SPAN_RATIO
    from models.tf import TransferFunction

    prov = dict(getattr(model, "provenance", {}) or {})
    out_span = prov.get("output_span_um")
    gains: list[tuple[str, float, float | None]] = []
    warnings: list[str] = []
    for t in model.terms:
        dyn = t.dynamics
        if not isinstance(dyn, TransferFunction):
            continue
        for p in dyn.poles:
            if abs(p.imag) < 1e-12 and p.real <= -NEGLIGIBLE_ALTERNATING:
                warnings.append(f"term {t.name!r}: a negative real pole {p.real:.6g}: a mode "
                                "that alternates sign every sample (not a thermal behaviour)")
        if t.gain_channel or not t.relative:
            continue
        k = float(t.gain) * dyn.dc_gain
        span = prov.get(f"{t.name}_input_span")
        gains.append((t.name, k, float(span) if isinstance(span, (int, float)) else None))
        if isinstance(span, (int, float)) and isinstance(out_span, (int, float)) \
                and out_span > 0.0:
            if abs(k) * span > PLAUSIBLE_DC_SPAN_RATIO * out_span:
                warnings.append(f"term {t.name!r}: DC gain {k:.4g} µm/K over its recorded "
                                f"span {span:.3g} K is {abs(k) * span:.3g} µm, out of "
                                f"proportion to the recorded displacement span "
                                f"{out_span:.3g} µm")
        elif abs(k) > MAX_PLAUSIBLE_UM_PER_K:
            warnings.append(f"term {t.name!r}: DC gain {k:.4g} µm/K is out of proportion for "
                            f"a machine tool (more than {MAX_PLAUSIBLE_UM_PER_K:g} µm/K)")
    for i, (n1, k1, s1) in enumerate(gains):
        for n2, k2, s2 in gains[i + 1:]:
            if k1 * k2 >= 0.0:
                continue
            if s1 is not None and s2 is not None and isinstance(out_span, (int, float)):
                big = abs(k1) * s1 > out_span and abs(k2) * s2 > out_span
            else:
                big = min(abs(k1), abs(k2)) > MAX_PLAUSIBLE_UM_PER_K / 2.0
            if big and abs(k1 + k2) < 0.25 * max(abs(k1), abs(k2)):
                warnings.append(f"terms {n1!r} and {n2!r} cancel: DC gains {k1:+.4g} and "
                                f"{k2:+.4g} µm/K predict the small difference of two large "
                                "terms (a sensor's fault becomes a large offset)")
    return warnings


def fallback_lines(fallbacks: dict[str, Any]) -> list[str]:
    """One line per fallback model of `describe_model`'s ``fallbacks``."""
    out = []
    for lost, fb in sorted(fallbacks.items()):
        terms = ", ".join(f"{t['name']} DC {t['dc_gain']:.4g}" for t in fb["terms"])
        fit = fb.get("validation_fit_percent")
        out.append(f"fallback without {lost}: {len(fb['terms'])} term(s) ({terms})"
                   + (f", validation {fit:.2f} %" if isinstance(fit, int | float) else ""))
    if not fallbacks:
        out.append("no fallback models: an invalid input holds, then ramps the offset to 0")
    return out


def _body(p: list[float]) -> str:
    re_, im = p
    return f"{re_:.7g}" if abs(im) < 1e-15 else f"{re_:.6g}{im:+.6g}j"


def format_zero(z: list[float]) -> str:
    return f"{_body(z)} (|z| = {math.hypot(*z):.7g})"


def format_pole(p: list[float], period_s: float) -> str:
    """A pole with its radius and, for a decaying mode that does not alternate
    sign (positive real part), its time constant in samples and in time."""
    return f"{_body(p)} (|p| = {math.hypot(*p):.7g}{_tau_text(p, period_s)})"


def _tau_text(p: list[float], period_s: float) -> str:
    tau_n = pole_time_constant_samples(p)
    if tau_n is None and p[0] < 0.0:
        if abs(p[1]) < 1e-15:
            return ", alternates sign every sample: no time constant"
        return ", turns more than a quarter turn a sample: no time constant"
    if tau_n is None:
        return ""
    return f", τ ≈ {tau_n:.0f} samples = {duration_text(tau_n * period_s)}"


def pole_time_constant_samples(p: list[float]) -> float | None:
    """−1/ln|p| for a pole inside the unit circle with a positive real part
    (the envelope's decay, in samples); None for a pole at 0, on or outside
    the unit circle, or with a real part ≤ 0 (a mode that alternates sign or
    turns faster than twice per 4 samples has no thermal time constant)."""
    mag = math.hypot(*p)
    if not (0.0 < mag < 1.0) or p[0] <= 0.0:
        return None
    return -1.0 / math.log(mag)


def duration_text(seconds: float) -> str:
    """A duration in the unit a person reads it in: s, min, h or d."""
    for unit, size in (("d", 86400.0), ("h", 3600.0), ("min", 60.0)):
        if seconds >= 2.0 * size:
            return f"{seconds / size:.3g} {unit}"
    return f"{seconds:.3g} s"
