"""The config's models: a ``[model]``-form table (a model file or inline terms)
built and checked against the config (its channels configured, stable within the
limits, fallbacks too, identified at the machine's period), its ``reference`` set;
a model's identity (`model_sha256`); the stand-in model of a recorder-only config.
Every refusal a `ConfigError` naming the key (`compd.config.loader` calls these for
``[model]``, its shadow and each ``[output.axes]`` axis's models).
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from compd.config.schema import ModelSection
from compd.errors import ConfigError
from compd.infiles import InputError, load_model
from drivers.addresses import Address
from models.compensation import CompensationModel, Term
from models.errors import ModelError
from models.modelfile import model_document, parse_model
from models.sanity import check_model
from models.tf import TransferFunction

#: what numpy raises on coefficients that overflow once normalised (1e308 over
#: 0.5): refused as a config error, like any other model the daemon cannot run
_NUMERIC_ERRORS = (ArithmeticError, ValueError)


def _numeric_reason(exc: Exception) -> str:
    return f"the model's coefficients cannot be evaluated ({type(exc).__name__}: {exc})"


def set_reference(model: CompensationModel, reference: dict[str, float],
                  key: str = "model.reference") -> None:
    """[model] reference: the reference state for `model` (its relative input channels;
    a channel it does not read is refused only when no model reads it)."""
    from models.modelfile import parse_reference

    mine = {ch: v for ch, v in reference.items() if ch in model.reference_channels}
    unknown = sorted(set(reference) - model.channels)
    if unknown:
        raise ConfigError(key, f"the model reads no channel {unknown[0]!r}; "
                          f"its reference channels: {sorted(model.reference_channels)}")
    try:
        model.calibration_reference = parse_reference(model, mine, key)
    except ModelError as exc:
        raise ConfigError(key, str(exc).removeprefix(f"{key}: ")) from None


def section_model(m: ModelSection, base: Path, channels: dict[str, Address],
                  period_s: float, key: str) -> CompensationModel:
    """The model a ``[model]``-form table describes (a file or inline terms; `key`
    the table's dotted key), checked against the config (`check_section_limits`), with its
    ``reference`` set."""
    if m.file is not None:
        model = model_from_ref(m.file, base, f"{key}.file")
        model_key = f"{key}.file"
    else:
        head: dict[str, Any] = {"name": m.name or "inline",
                                "period_s": m.period_s or period_s}
        try:
            model = parse_model({"model": head, "terms": m.terms or []}, where=key)
        except ModelError as exc:
            raise ConfigError(f"{key}.terms", str(exc)) from None
        except _NUMERIC_ERRORS as exc:
            raise ConfigError(f"{key}.terms", _numeric_reason(exc)) from None
        model_key = f"{key}.terms"
    check_section_limits(model, channels, period_s, model_key, m)
    if m.reference is not None:
        set_reference(model, m.reference, f"{key}.reference")
    return model


def model_from_ref(ref: str, base: Path, key: str) -> CompensationModel:
    """The model file `ref` (relative to `base`, the config's folder), else the
    bundled library model of that name; a refusal names `key`."""
    p = Path(ref)
    candidate = p if p.is_absolute() else base / p
    try:
        if candidate.exists():
            return load_model(candidate)
        if p.suffix == "" and "/" not in ref:
            return load_model(ref)  # a bundled library model
    except (ModelError, InputError) as exc:
        raise ConfigError(key, str(exc)) from None
    except _NUMERIC_ERRORS as exc:
        raise ConfigError(key, _numeric_reason(exc)) from None
    raise ConfigError(key, f"no model file at {candidate} (and no bundled model named {ref!r})")


def model_sha256(model: CompensationModel) -> str:
    doc = model_document(model)
    text = json.dumps(doc, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def check_section_limits(model: CompensationModel, channels: dict[str, Address], period_s: float,
                         key: str, section: ModelSection) -> None:
    """`check_limits` at the limits `section` (a ``[model]``-form table) sets."""
    check_limits(model, channels, period_s, key, max_dc_gain_um=section.max_dc_gain_um,
                  max_time_constant_s=section.max_time_constant_s)


def check_limits(model: CompensationModel, channels: Mapping[str, Address], period_s: float,
                 key: str, *, max_dc_gain_um: float, max_time_constant_s: float) -> None:
    """The one check of a model against a config: its channels configured, stable
    within the limits (its fallbacks too), identified at the config's period."""
    try:
        model.check_channels(channels)
        check_model(model, max_dc_gain_um=max_dc_gain_um,
                    max_time_constant_s=max_time_constant_s)
        for lost, fb in model.fallbacks.items():
            try:
                check_model(fb, max_dc_gain_um=max_dc_gain_um,
                            max_time_constant_s=max_time_constant_s)
            except ModelError as exc:
                raise ModelError(f"fallback for {lost!r}: {exc}") from None
    except ModelError as exc:
        raise ConfigError(key, str(exc)) from None
    if not math.isclose(model.period_s, period_s, rel_tol=1e-9):
        raise ConfigError(key, f"the model's period_s ({model.period_s:g} s) differs from "
                               f"machine.period_s ({period_s:g} s); a model identified at one "
                               "sample period is wrong at another")


#: the name of the stand-in model of a recorder-only config without [model]
RECORDER_MODEL_NAME = "none (recorder only)"


def recorder_model(channels: Mapping[str, Address], period_s: float) -> CompensationModel:
    """A recorder-only config's stand-in for [model]: one zero-gain static term per
    channel, so the cycle validates every channel (a cycle is valid when all are) and
    predicts nothing; its output is not recorded (`compd.core.cycle`)."""
    terms = [Term(f"record_{i}", {name: 1.0}, TransferFunction([1.0], [1.0], name=name),
                  gain=0.0, relative=False)
             for i, name in enumerate(sorted(channels))]
    return CompensationModel(terms, period_s, name=RECORDER_MODEL_NAME)
