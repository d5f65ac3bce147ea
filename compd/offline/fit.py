"""`compd fit` as a library: `fit_model(FitRequest)` reads and checks the
calibration records (`compd.offline.fit_records`), identifies the terms
(`compd.offline.fit_identify`), builds the model with its provenance,
calibration reference and fallbacks (`compd.offline.fit_fallback`), checked as
`compd check` would (`compd.offline.fit_checks`). The command
(`compd.commands.fit`) parses the arguments, writes the model file and prints."""

from __future__ import annotations

import math
import re
import shlex
import sys
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from compd import __version__
from compd.offline.fit_identify import identify_terms
from compd.offline.fit_records import (
    LONG_RECORD_ROWS,
    calibration_rows,
    check_folds,
    keep_freed_arrays,
    read_records,
    return_freed_arrays,
)
from compd.offline.fit_request import (
    MAX_FIT_TERMS,
    FitRequest,
    FitRun,
)
from compd.sysexits import EX_USAGE

if TYPE_CHECKING:
    from compd.offline.fit_fallback import Fallbacks
    from compd.offline.records import Record
    from models.compensation import CompensationModel, Term

_TERM_RE = re.compile(r"\s*([+-]?)\s*([A-Za-z_][A-Za-z0-9_.]*)\s*")



def parse_term(text: str) -> tuple[str, dict[str, float]]:
    """``[name=]ch[(+|-)ch…]`` -> (name, {channel: ±1})."""
    name, eq, expr = text.partition("=")
    if not eq:
        name, expr = text.strip(), text
    inputs: dict[str, float] = {}
    pos = 0
    while pos < len(expr):
        m = _TERM_RE.match(expr, pos)
        if m is None or m.end() == pos or (pos > 0 and not m.group(1)):
            raise ValueError(f"--term {text!r}: expected channels joined by + or -")
        inputs[m.group(2)] = inputs.get(m.group(2), 0.0) + (-1.0 if m.group(1) == "-" else 1.0)
        pos = m.end()
    if not inputs or not name.strip():
        raise ValueError(f"--term {text!r}: no channel")
    return name.strip(), inputs



def _fixed_terms(specs: list[str], records: list[Record]) -> tuple[list[Term], list[Any]]:
    """The fixed terms and their summed prediction over each record."""

    from compd.infiles import load_model
    from compd.offline.model_replay import replay_model
    from models.compensation import CompensationModel
    from models.errors import ModelError

    terms: list[Term] = []
    totals: list[Any] = [0.0 for _ in records]  # no array of zeros per record without --fixed
    for spec in specs:
        path, sep, term_name = spec.rpartition(":")
        if not sep or not path or not term_name:
            raise ModelError(f"--fixed {spec!r}: expected MODEL:TERM")
        source = load_model(path)
        found = [t for t in source.terms if t.name == term_name]
        if not found:
            raise ModelError(f"--fixed {spec!r}: {path} has no term {term_name!r}; it has "
                             f"{[t.name for t in source.terms]}")
        one = CompensationModel(found, source.period_s, name=f"{path}:{term_name}")
        for i, record in enumerate(records):
            totals[i] = totals[i] + replay_model(one, record)
        one.reset()
        terms.append(found[0])
    return terms, totals



def _text(value: Any) -> Any:
    """`value` with every string made writable as UTF-8: a file name or
    argument of raw bytes (lone surrogates in Python) is kept with those
    bytes backslash-escaped, so the model file is written and read again."""
    if isinstance(value, str):
        return value.encode("utf-8", "backslashreplace").decode("utf-8")
    if isinstance(value, dict):
        return {_text(k): _text(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_text(v) for v in value]
    return value


def _provenance(run: FitRun, records: list[Record],
                info: list[dict[str, Any]]) -> dict[str, Any]:
    prov: dict[str, Any] = {
        "tool": "compd fit",
        "compd_version": __version__,
        "command_line": run.request.command_line
        or "compd fit " + shlex.join([*run.request.data, "--column", run.request.output]),
        "date": datetime.now(UTC).isoformat(timespec="seconds"),
        "data_file": str(run.request.data[0]),
        "data_sha256": records[0].sha256,
        "samples": sum(len(r) for r in records),
        "period_s": records[0].period_s,
        "kind": run.request.kind,
        "fixed_terms": list(run.request.fixed),
        "max_time_constant_days": run.request.max_time_constant_days,
    }
    if len(records) > 1:
        prov["data_files"] = [str(p) for p in run.request.data]
        prov["data_sha256s"] = [r.sha256 for r in records]
        prov["samples_per_record"] = [len(r) for r in records]
    if run.request.validation_record:
        prov["validation_records"] = [str(p) for p in run.request.validation_record]
    if run.request.positions:  # what compd replay --slope-model checks
        prov["positions_column"] = run.request.output
        prov["reference_position_mm"] = run.request.reference_position_mm
    if run.request.fit_from is not None:
        prov["calibrated_from_s"] = run.request.fit_from
    if run.request.fit_until is not None:
        prov["calibrated_until_s"] = run.request.fit_until
    if not run.request.adaptation:  # the command learns them after the fit, when asked
        prov["adaptation_not_learnt"] = NOT_ASKED
    if run.search_table:
        prov["candidates"] = list(run.request.candidates)
        prov["inputs_chosen"] = list(run.search_chosen)
        prov["subsets_tried"] = [f"{' + '.join(t['inputs'])}: validation "
                                 f"{t['validation_fit_percent']:.2f} % ({t['screen']} screen)"
                                 for t in run.search_table]
    for t in info:
        key = t["name"]
        if t["kind"] == "tf":
            prov[f"{key}_orders"] = (f"numerator {t['orders']['numerator_length']}, "
                                     f"denominator {t['orders']['denominator_order']}")
            prov[f"{key}_dc_gain_um_per_k"] = t["dc_gain_um_per_k"]
            prov[f"{key}_input_span"] = t["input_span"]
            prov["output_span_um"] = t["output_span_um"]
            if t["arx_fit_percent"] is not None:  # None: no stable ARX at the orders chosen
                prov["arx_fit_percent"] = t["arx_fit_percent"]
            prov["oe_fit_percent"] = t["oe_fit_percent"]
            sel = t["selection"]
            prov["structure"] = sel["structure"]
            prov["validation_fit_percent"] = sel["validation_fit_percent"]
            if "stability" in sel:
                from compd.offline.fit_hedge import stability_lines

                prov["choice_stability"] = sel["stability"]["share"]
                prov["choice_stability_text"] = [ln.strip() for ln in stability_lines(sel)]
            if "candidates" in sel:
                prov["runners_up"] = [f"{c['structure']}: validation "
                                      f"{c['validation_fit_percent']:.2f} %"
                                      for c in sel["candidates"]]
        else:
            prov[f"{key}_fit_percent"] = t["fit_percent"]
    return prov


def _search_specs(run: FitRun, records: list[Record]
                  ) -> list[tuple[str, dict[str, float]]]:
    """--candidates: the inputs chosen by validation, one term each."""
    from compd.offline.fit_search import search_inputs
    from models.errors import ModelError
    from models.identify.segments import pole_radius

    if run.request.kind != "tf" or run.request.fixed or run.request.validation_record:
        raise ModelError("--candidates goes with --kind tf, without --fixed or "
                         "--validation-record")
    radius = pole_radius(records[0].period_s, run.request.max_time_constant_days * 86400.0)
    chosen, table = search_inputs(run, records, [r.column(run.request.output) for r in records],
                                  radius)
    run.search_table = table
    run.search_chosen = chosen
    return [(name, {name: 1.0}) for name in chosen]


#: said above a fitted model's [reference] table
REFERENCE_COMMENT = (
    "# The reference state: the temperatures of the calibration record's first sample\n"
    "# ({record}), from which the fit measured every relative input's change. The model's\n"
    "# growth is zero here; the tool was touched off in this state. The daemon starts\n"
    "# from it on a warm machine (a config's [model] reference overrides it).\n")


def calibration_reference(model: CompensationModel, record: Record) -> dict[str, float]:
    """The reference the fit used for `model`'s relative input channels: `record`'s
    first sample ({} when one of them is not a finite number there)."""
    refs = {ch: float(record.column(ch)[0]) for ch in sorted(model.reference_channels)}
    return refs if all(math.isfinite(v) for v in refs.values()) else {}


def save_model(model: CompensationModel, path: Path, record: str = "") -> None:
    """The model file, its [reference] table with a comment saying what it is."""
    from models.modelfile import dumps_model, model_document

    text = dumps_model(model_document(model))
    note = REFERENCE_COMMENT.format(record=record or "the first DATA")
    text = text.replace("\n[reference]\n", "\n" + note + "[reference]\n", 1)
    if text.startswith("[reference]\n"):
        text = note + text
    path.write_text(text, encoding="utf-8")


def term_specs(request: FitRequest) -> list[tuple[str, dict[str, float]]]:
    """The terms `request.term` asks for, as (name, {channel: ±1}); [] with
    `request.candidates` (the one or the other). InputError (64) for too many
    terms, ModelError for one that does not parse."""
    from models.errors import ModelError

    if len(request.term) > MAX_FIT_TERMS:
        from compd.infiles import InputError

        raise InputError(f"--term given {len(request.term)} times; at most {MAX_FIT_TERMS} "
                         "(each one more set of coefficients to identify: 60 took minutes)",
                         EX_USAGE)
    try:
        specs = [parse_term(t) for t in request.term]
    except ValueError as exc:
        raise ModelError(str(exc)) from None
    if bool(specs) == bool(request.candidates):
        raise ModelError("give the inputs with --term, or let --candidates choose them "
                         "(one of the two)")
    return specs


@dataclass(frozen=True)
class FitResult:
    """A fit's model (not yet written) and what the printing and the provenance
    say of it."""

    model: CompensationModel
    #: per term: its kind, inputs, orders, poles, DC gain, the structure selection
    info: list[dict[str, Any]]
    #: the records as fitted (the calibration rows)
    records: list[Record]
    #: the fallbacks fitted (None: `no_fallbacks`)
    fallbacks: Fallbacks | None
    #: the input search's table and choice (None and []: the terms were given)
    search_table: list[dict[str, Any]] | None
    search_chosen: list[str]
    #: the chosen model's residuals on rows it was not calibrated on
    heldout_residuals: Any


def fit_model(request: FitRequest, run: FitRun | None = None) -> FitResult:
    """The model `request` asks for, identified from its records (warnings on
    stderr); ModelError, RecordError or InputError when it cannot be. `run`: the
    working state to fill (`FitRun.of(request)`), for a caller that reads what the
    selection and the last word saw, also when the fit is refused."""
    from compd.offline.records import speed_warnings
    from models.compensation import CompensationModel

    run = run if run is not None else FitRun.of(request)
    specs = term_specs(request)
    data = list(request.data)
    channels = {ch for _, inputs in specs for ch in inputs}
    records = calibration_rows(run, read_records(data, request, channels))
    check_folds(run, records)
    if sum(len(r) for r in records) > LONG_RECORD_ROWS:
        return_freed_arrays()
    else:
        keep_freed_arrays()
    if request.candidates:
        specs = _search_specs(run, records)
        channels = {ch for _, inputs in specs for ch in inputs}
        records = calibration_rows(run, read_records(data, request, channels))
    holdout = read_records(list(request.validation_record), request, channels, records[0])
    for w in [w for r in records for w in speed_warnings(r)] if len(records) == 1 else []:
        print(f"compd fit: warning: {w}", file=sys.stderr)
    fixed, fixed_preds = _fixed_terms(list(request.fixed), records)
    ys = [r.column(request.output) - f if fixed else r.column(request.output)
          for r, f in zip(records, fixed_preds, strict=True)]
    terms, info = identify_terms(run, records, ys, specs, holdout)
    names = ", ".join(Path(p).name for p in data)
    name = request.name or f"fitted from {names}"
    model = CompensationModel(fixed + terms, records[0].period_s, name=_text(name),
                              description=_text(f"compd fit --kind {request.kind} on {names}"),
                              provenance=_text(_provenance(run, records, info)))
    from compd.offline.fit_checks import gate

    model.calibration_reference = calibration_reference(model, records[0])
    if not request.adaptation:  # settings whose worth is unknown start stood down
        model.adaptation = {"unproven": True}
    gate(model, request.force)  # compd check's warnings: nothing written without --force
    fallbacks = None
    if not request.no_fallbacks:  # a model for the loss of each input, in the same file
        from compd.offline.fit_fallback import fit_fallbacks

        reads = {ch for t in terms for ch in t.inputs}
        fallbacks = fit_fallbacks(run, records, ys, specs, holdout, fixed, reads)
        model.fallbacks = fallbacks.models
    return FitResult(model, info, records, fallbacks, run.search_table, run.search_chosen,
                     run.heldout_residuals)


#: why a model fitted without `--adaptation` carries no learnt [adaptation] settings
NOT_ASKED = "not asked for (compd fit without --adaptation)"


def suggest_adaptation(fit: FitResult, request: FitRequest, measured: list[Any],
                       simulated: list[Any], period_s: float
                       ) -> tuple[dict[str, Any], str | None]:
    """(the learnt settings, None) from the residual of `measured` less `simulated` and
    `fit`'s held-out residuals; or ({}, why none were learnt: the records shorter than
    the lag, or not asked), for the model file to say (`adaptation_provenance`)."""
    if not request.adaptation:
        return {}, NOT_ASKED
    from compd.offline.probes import suggest_settings

    residuals = [m - s for m, s in zip(measured, simulated, strict=True)]
    try:
        return suggest_settings(residuals, period_s, request.adaptation_lag_s,
                                fit.heldout_residuals).as_dict(), None
    except ValueError as exc:
        return {}, str(exc)


def adaptation_provenance(adapt: dict[str, Any], why_not: str | None) -> dict[str, Any]:
    """What a model file's provenance says of its [adaptation] table: what the settings
    were learnt on and over which lag, or why none were (the estimator then starts stood
    down on it, `models.adaptation_params.mark_unproven`)."""
    if why_not is not None:
        return {"adaptation_not_learnt": _text(why_not)}
    return {"adaptation_learnt_on": adapt["drift_from"], "adaptation_lag_s": adapt["lag_s"]}
