"""The model file format (TOML): the document's parser and writer.

Files are read by `compd.infiles.load_model` (the one loader: regular files
only, at most 1 MiB, nesting bounded), which hands the document to
`parse_model` here; bundled models are found by `library_path`.

::

    [model]
    name = "SP2 per-spindle"
    period_s = 1.0
    description = "paper 000, eq. 2"

    [[terms]]
    name = "spindle"
    kind = "tf"                      # tf | greybox | mbotv
    inputs = { bearing = 1.0 }       # channel -> coefficient, relative to T_ref
    a = ["16.0005", "-15.9975"]      # strings keep every printed digit
    b = ["1", "-0.99983"]
    gain = 1.0                       # or gain_channel = "clamp_gain"

    [adaptation]                     # optional: the probe estimator's settings learnt
    bias_rw_um_per_sqrt_h = 2.7      # from the calibration residual (compd fit
    probe_noise_um = 0.07            # --adaptation); any field of
                                     # models.adaptation.AdaptationParams
    [reference]                      # optional: the calibration's reference state,
    bearing = 20.0                   # °C per relative input channel (zero growth);
    ambient = 20.0                   # every relative input channel, or none
    [provenance]                     # free: data hash, orders, fit %, date

    [[fallback]]                     # optional, one per input channel it covers: the
    lost = "ambient"                 # model on the remaining channels used while
    model = { name = "...", period_s = 1.0 }   # `lost` is invalid (compd fit writes
    terms = [ { name = "spindle", ... } ]      # them); it must not read `lost`, and
    provenance = { ... }                       # reads only the main model's channels

Fallbacks live in the model's own file so a model stays one verifiable file
and its hash (the checkpoint's ``model_sha256``) covers them.

Grey-box terms take ``p = [p1, p2, p3]`` (or six with ``switch_channel``)
and ``relative = false`` for power inputs; MBOTV terms take ``alpha``,
``beta``, ``gamma``, ``k`` or ``tau_s``, optional ``delta``. Every key is
checked: unknown keys and wrong types are refused with the key path.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from typing import Any

from models import tomltext
from models.coefficients import printed_text
from models.compensation import CompensationModel, Term
from models.errors import ModelError
from models.greybox import GreyBox
from models.mbotv import Mbotv
from models.sanity import check_period
from models.tf import TransferFunction

#: a transfer function's a or b holds a few coefficients (`compd fit` tries orders up to
#: 8); 3,000 of them made the poles' eigenvalue problem run for minutes in `check`
MAX_COEFFICIENTS = 32
#: terms of one model (a machine has a handful of heat sources)
MAX_TERMS = 64

_MODEL_KEYS = {"name", "period_s", "description", "channels"}
_COMMON_TERM_KEYS = {"name", "kind", "inputs", "gain", "gain_channel", "relative"}
_KIND_KEYS = {
    "tf": {"a", "b"},
    "greybox": {"p", "switch_channel"},
    "mbotv": {"alpha", "beta", "gamma", "k", "tau_s", "delta"},
}


def _number(doc: Mapping[str, Any], key: str, where: str, default: float | None = None) -> float:
    if key not in doc:
        if default is None:
            raise ModelError(f"{where}.{key}: missing")
        return default
    v = doc[key]
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise ModelError(f"{where}.{key}: must be a finite number, got {v!r}")
    return float(v)


def _str(doc: Mapping[str, Any], key: str, where: str, default: str | None = None) -> str:
    v = doc.get(key, default)
    if not isinstance(v, str) or (default is None and not v):
        raise ModelError(f"{where}.{key}: must be a non-empty string, got {v!r}")
    return v


def _check_keys(doc: Mapping[str, Any], allowed: set[str], where: str) -> None:
    unknown = sorted(set(doc) - allowed)
    if unknown:
        raise ModelError(f"{where}: unknown key(s) {unknown}; allowed: {sorted(allowed)}")


def parse_term(doc: Any, period_s: float, where: str) -> Term:
    if not isinstance(doc, Mapping):
        raise ModelError(f"{where}: a term must be a table, got {doc!r}")
    kind = doc.get("kind", "tf")
    if kind not in _KIND_KEYS:
        raise ModelError(f"{where}.kind: unknown kind {kind!r}; known: {sorted(_KIND_KEYS)}")
    _check_keys(doc, _COMMON_TERM_KEYS | _KIND_KEYS[kind], where)
    name = _str(doc, "name", where)
    inputs = doc.get("inputs")
    if not isinstance(inputs, Mapping) or not inputs:
        raise ModelError(f"{where}.inputs: a table of channel = coefficient is required, "
                         f"got {inputs!r}")
    gain_channel = doc.get("gain_channel")
    if gain_channel is not None and (not isinstance(gain_channel, str) or not gain_channel):
        raise ModelError(f"{where}.gain_channel: must be a channel name, got {gain_channel!r}")
    if gain_channel is not None and "gain" in doc:
        raise ModelError(f"{where}: give either gain or gain_channel, not both")
    gain = _number(doc, "gain", where, 1.0)
    relative = doc.get("relative", kind != "greybox")
    if not isinstance(relative, bool):
        raise ModelError(f"{where}.relative: must be true or false, got {relative!r}")
    dyn: TransferFunction | GreyBox | Mbotv
    switch_channel: str | None = None
    if kind == "tf":
        for key in ("a", "b"):
            if key not in doc:
                raise ModelError(f"{where}.{key}: missing (numerator a and denominator b)")
            if isinstance(doc[key], list) and len(doc[key]) > MAX_COEFFICIENTS:
                raise ModelError(f"{where}.{key}: {len(doc[key])} coefficients; at most "
                                 f"{MAX_COEFFICIENTS} (a thermal filter has a few)")
        dyn = TransferFunction(doc["a"], doc["b"], name=f"{where}({name})")
    elif kind == "greybox":
        p = doc.get("p")
        if not isinstance(p, list) or not all(
                isinstance(v, int | float) and not isinstance(v, bool) for v in p):
            raise ModelError(f"{where}.p: must be a list of numbers, got {p!r}")
        dyn = GreyBox([float(v) for v in p], period_s, name=f"{where}({name})")
        sw = doc.get("switch_channel")
        if sw is not None and not isinstance(sw, str):
            raise ModelError(f"{where}.switch_channel: must be a channel name, got {sw!r}")
        if (sw is None) == dyn.switched:
            raise ModelError(f"{where}: six parameters p1..p6 go with a switch_channel "
                             "(u2), three without")
        switch_channel = sw
    else:
        if ("k" in doc) == ("tau_s" in doc):
            raise ModelError(f"{where}: give exactly one of k or tau_s")
        alpha, beta = _number(doc, "alpha", where), _number(doc, "beta", where)
        gamma, delta = _number(doc, "gamma", where), _number(doc, "delta", where, 0.0)
        label = f"{where}({name})"
        if "k" in doc:
            dyn = Mbotv(alpha, beta, _number(doc, "k", where), gamma, period_s, delta, label)
        else:
            dyn = Mbotv.from_tau(alpha, beta, _number(doc, "tau_s", where), gamma, period_s,
                                 delta, label)
    return Term(name=name, inputs={str(k): v for k, v in inputs.items()}, dynamics=dyn,
                gain=gain, gain_channel=gain_channel, relative=relative,
                switch_channel=switch_channel)


#: the top-level tables a model file may hold
MODEL_FILE_KEYS = frozenset({"model", "terms", "provenance", "adaptation", "reference",
                             "fallback"})


def parse_model(doc: Mapping[str, Any], where: str = "model") -> CompensationModel:
    """Build a model from a parsed TOML document (the file, or a config's inline model)."""
    _check_keys(doc, set(MODEL_FILE_KEYS), where)
    head = doc.get("model", {})
    if not isinstance(head, Mapping):
        raise ModelError(f"{where}.model: must be a table")
    _check_keys(head, _MODEL_KEYS, f"{where}.model")
    period_s = _number(head, "period_s", f"{where}.model", 1.0)
    check_period(period_s, f"{where}.model.period_s")
    terms_doc = doc.get("terms")
    if not isinstance(terms_doc, list) or not terms_doc:
        raise ModelError(f"{where}.terms: at least one [[terms]] table is required")
    if len(terms_doc) > MAX_TERMS:
        raise ModelError(f"{where}.terms: {len(terms_doc)} terms; at most {MAX_TERMS}")
    terms = [parse_term(t, period_s, f"terms[{i}]") for i, t in enumerate(terms_doc)]
    provenance = doc.get("provenance", {})
    if not isinstance(provenance, Mapping):
        raise ModelError(f"{where}.provenance: must be a table")
    model = CompensationModel(terms, period_s, name=_str(head, "name", f"{where}.model", "model"),
                              description=_str(head, "description", f"{where}.model", ""),
                              provenance=dict(provenance))
    model.adaptation = parse_adaptation(doc.get("adaptation", {}), f"{where}.adaptation")
    if "reference" in doc:
        model.calibration_reference = parse_reference(model, doc["reference"],
                                                      f"{where}.reference")
    declared = head.get("channels")
    if declared is not None:
        if not isinstance(declared, list) or not all(isinstance(c, str) for c in declared):
            raise ModelError(f"{where}.model.channels: must be a list of channel names")
        model.check_channels(declared)
    if "fallback" in doc:
        model.fallbacks = parse_fallbacks(model, doc["fallback"], f"{where}.fallback")
    return model


#: keys of one [[fallback]] table
_FALLBACK_KEYS = {"lost", "model", "terms", "provenance", "reference"}


def parse_fallbacks(model: CompensationModel, doc: Any, where: str
                    ) -> dict[str, CompensationModel]:
    """The [[fallback]] tables: for each, the channel lost and a model on the others
    (its period the main model's, its channels among the main model's but the lost
    one; one fallback per lost channel)."""
    if not isinstance(doc, list):
        raise ModelError(f"{where}: must be [[fallback]] tables")
    if len(doc) > MAX_TERMS:
        raise ModelError(f"{where}: {len(doc)} fallbacks; at most {MAX_TERMS}")
    out: dict[str, CompensationModel] = {}
    for i, table in enumerate(doc):
        at = f"{where}[{i}]"
        if not isinstance(table, Mapping):
            raise ModelError(f"{at}: must be a table")
        _check_keys(table, _FALLBACK_KEYS, at)
        lost = _str(table, "lost", at)
        if lost not in model.channels:
            raise ModelError(f"{at}.lost: the model reads no channel {lost!r}; it reads "
                             f"{sorted(model.channels)}")
        if lost in out:
            raise ModelError(f"{at}.lost: a second fallback for {lost!r}")
        sub = {k: v for k, v in table.items() if k != "lost"}
        fb = parse_model(sub, at)
        if fb.fallbacks:
            raise ModelError(f"{at}: a fallback has no fallbacks of its own")
        if lost in fb.channels:
            raise ModelError(f"{at}.terms: the fallback for {lost!r} reads {lost!r}")
        extra = sorted(fb.channels - model.channels)
        if extra:
            raise ModelError(f"{at}.terms: reads {extra}, which the main model does not")
        if not math.isclose(fb.period_s, model.period_s, rel_tol=1e-9):
            raise ModelError(f"{at}.model.period_s: {fb.period_s:g} s, the model's is "
                             f"{model.period_s:g} s")
        out[lost] = fb
    return out


def parse_reference(model: CompensationModel, doc: Any, where: str) -> dict[str, float]:
    """A reference state: a finite temperature for every relative input channel of
    `model` (the state in which its growth is zero), nothing else."""
    if not isinstance(doc, Mapping):
        raise ModelError(f"{where}: must be a table of channel = temperature")
    need = model.reference_channels
    _check_keys(doc, need, where)
    missing = sorted(need - set(doc))
    if missing:
        raise ModelError(f"{where}: no reference temperature for channel(s) {missing}")
    return {ch: _number(doc, ch, where) for ch in sorted(need)}


def parse_adaptation(doc: Any, where: str) -> dict[str, Any]:
    """A model's [adaptation] table: settings of `models.adaptation.AdaptationParams`,
    each checked there (ModelError naming the key)."""
    from dataclasses import fields

    from models.adaptation import AdaptationParams

    if not isinstance(doc, Mapping):
        raise ModelError(f"{where}: must be a table")
    _check_keys(doc, {f.name for f in fields(AdaptationParams)}, where)
    table = dict(doc)
    try:
        AdaptationParams(**table)
    except (TypeError, ValueError) as exc:
        first = str(exc).split("; ")[0]
        raise ModelError(f"{where}.{first}") from None
    return table


def library_names() -> list[str]:
    root = resources.files("models") / "library"
    return sorted(p.name.removesuffix(".toml") for p in root.iterdir()
                  if p.name.endswith(".toml"))


def library_path(name: str) -> Path | None:
    candidate = resources.files("models") / "library" / f"{name}.toml"
    return Path(str(candidate)) if candidate.is_file() else None


# -- writing ---------------------------------------------------------------------------------

def term_document(term: Term) -> dict[str, Any]:
    doc: dict[str, Any] = {"name": term.name}
    dyn = term.dynamics
    if isinstance(dyn, TransferFunction):
        doc["kind"] = "tf"
    elif isinstance(dyn, GreyBox):
        doc["kind"] = "greybox"
    else:
        doc["kind"] = "mbotv"
    doc["inputs"] = dict(term.inputs)
    if term.gain_channel:
        doc["gain_channel"] = term.gain_channel
    else:
        doc["gain"] = term.gain
    if term.relative != (doc["kind"] != "greybox"):
        doc["relative"] = term.relative
    if isinstance(dyn, TransferFunction):
        doc["a"] = [printed_text(c) for c in dyn.orig_num]
        doc["b"] = [printed_text(c) for c in dyn.orig_den]
    elif isinstance(dyn, GreyBox):
        doc["p"] = list(dyn.p)
        if term.switch_channel:
            doc["switch_channel"] = term.switch_channel
    else:
        doc.update(alpha=dyn.alpha, beta=dyn.beta, delta=dyn.delta, k=dyn.k, gamma=dyn.gamma)
    return doc


def model_document(model: CompensationModel) -> dict[str, Any]:
    doc: dict[str, Any] = {
        "model": {"name": model.name, "period_s": model.period_s,
                  "description": model.description},
        "terms": [term_document(t) for t in model.terms],
    }
    if model.adaptation:
        doc["adaptation"] = dict(model.adaptation)
    if model.calibration_reference:
        doc["reference"] = dict(model.calibration_reference)
    if model.provenance:
        doc["provenance"] = dict(model.provenance)
    if model.fallbacks:
        doc["fallback"] = [{"lost": lost, **model_document(fb)}
                           for lost, fb in sorted(model.fallbacks.items())]
    return doc


def dumps_model(doc: Mapping[str, Any]) -> str:
    """TOML text for a model document."""
    return tomltext.dumps(doc, header_depth=1)


def save_model(model: CompensationModel, path: str | Path) -> None:
    Path(path).write_text(dumps_model(model_document(model)), encoding="utf-8")
