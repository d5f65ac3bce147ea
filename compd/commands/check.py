"""`compd check MODEL_OR_CONFIG [--json]`: load, analyse, refuse what is unsafe.

For a model file (or a bundled library name such as ``sp2``) it prints per
term: poles, zeros, stability, DC gain (µm/K) and its sensitivity to the
printed digits. A daemon config is handed to `compd.config.loader` when present.
Any invalid input exits 78 (EX_CONFIG) with one message naming the key.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import Any

HELP = "validate a model file or a daemon config and print poles, DC gains, sensitivity"

#: without a recorded range, a temperature term's DC gain above this (µm/K) is
#: out of proportion for a machine tool (steel grows 11.5 µm per metre and kelvin)
MAX_PLAUSIBLE_UM_PER_K = 50.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("path", metavar="MODEL_OR_CONFIG",
                        help="model file, bundled model name (e.g. sp2), daemon config, or "
                             "a directory of daemon configs (as compd run DIR)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--connect", action="store_true",
                        help="(config) also connect and read each channel once")


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


def _print_text(report: dict[str, Any]) -> None:
    period = float(report["period_s"])
    print(f"model {report['model']!r}: period {report['period_s']} s, "
          f"{len(report['terms'])} term(s)")
    for t in report["terms"]:
        ins = " ".join(f"{c:+g}·{ch}" for ch, c in t["inputs"].items())
        print(f"\nterm {t['name']!r} ({t['kind']}): input {ins}, gain {t['gain']}")
        poles = ", ".join(format_pole(p, period) for p in t["poles"])
        print(f"  poles: {poles}")
        if t.get("zeros"):
            print(f"  zeros: {', '.join(_fmt_zero(z) for z in t['zeros'])}")
        for root in t.get("cancelled_unit_circle", []):
            print(f"  note: a pole at z = {root} is cancelled exactly by a zero at z = {root}; "
                  "the reduced form is used (stable)")
        print(f"  stable: {'yes' if t['stable'] else 'NO'}")
        print(f"  DC gain: {t['dc_gain']:.6g} {t['dc_gain_unit']}")
        if "dc_gain_note" in t:
            print(f"  sensitivity: {t['dc_gain_note']}")
    print()
    for line in fallback_lines(report.get("fallbacks", {})):
        print(line)


def _body(p: list[float]) -> str:
    re_, im = p
    return f"{re_:.7g}" if abs(im) < 1e-15 else f"{re_:.6g}{im:+.6g}j"


def _fmt_zero(z: list[float]) -> str:
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


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from compd.errors import ConfigError
    from models.errors import ModelError
    from models.sanity import check_model

    if Path(args.path).is_dir():  # as `compd run DIR`: every *.toml in it, one machine each
        from compd.commands.check_config import report_directory

        return report_directory(Path(args.path), args)
    kind, loaded = _load(args.path)
    if kind == "config":
        from compd.commands.check_config import report

        rc: int = report(loaded, args)
        return rc
    if args.connect:
        from compd.infiles import InputError
        from compd.sysexits import EX_USAGE

        raise InputError(f"--connect reads a daemon config's channels; {args.path} is a "
                         "model", EX_USAGE)
    try:
        check_model(loaded)  # physically absurd: refused (models.sanity)
        for lost, fb in loaded.fallbacks.items():
            try:
                check_model(fb)
            except ModelError as exc:
                raise ModelError(f"fallback for {lost!r}: {exc}") from None
    except ModelError as exc:
        raise ConfigError("", str(exc)) from None
    report_ = describe_model(loaded)
    flags = plausibility(loaded)
    if args.json:
        print(json.dumps({"terms": report_["terms"], "model": report_["model"],
                          "period_s": report_["period_s"], "implausible": flags,
                          "fallbacks": report_.get("fallbacks", {})}))
    else:
        _print_text(report_)
    for w in flags:
        print(f"compd check: warning: {w}", file=sys.stderr)
    return 0


def _load(path: str) -> tuple[str, Any]:
    """("config", LoadedConfig) or ("model", CompensationModel): the file read
    once by the reader `compd run` uses (`compd.infiles.read_toml_document`);
    a daemon config is one with [controller] or [machine]."""
    import os
    from pathlib import Path

    from compd.config.loader import parse_config
    from compd.errors import ConfigError
    from compd.infiles import load_model, read_toml_document
    from models.errors import ModelError
    from models.modelfile import library_names, library_path, parse_model

    p = Path(path)
    try:
        if path and not os.path.lexists(p) and p.suffix == "" and library_path(path):
            return "model", load_model(path)
        if path and not os.path.lexists(p) and p.suffix == "" and "/" not in path:
            from compd.infiles import InputError

            raise InputError(f"{path}: no such file, nor a bundled model (bundled: "
                             f"{', '.join(library_names())})")
        text, doc = read_toml_document(p, "model or config file")
        if "controller" in doc or "machine" in doc:
            return "config", parse_config(doc, p.resolve(), text)
        return "model", parse_model(doc)
    except ModelError as exc:
        raise ConfigError("", str(exc)) from None
