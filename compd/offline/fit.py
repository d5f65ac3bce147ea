"""`compd fit` as a library: the calibration records read and checked, the
terms identified (`compd.offline.fit_identify`), the model built with its
provenance, calibration reference and fallbacks (`compd.offline.fit_fallback`),
checked as `compd check` would (`compd.offline.fit_checks`). The command
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
from compd.offline.fit_request import (
    DEFAULT_FOLDS,
    MAX_FIT_TERMS,
    MIN_FOLD_ROWS,
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



def _check_folds(run: FitRun, records: list[Record]) -> None:
    """--folds as given, if each of its K + 1 blocks of the shortest record
    holds MIN_FOLD_ROWS rows (else a usage error, 64, naming the flag); the
    default when not given."""
    from compd.infiles import InputError

    if run.request.folds is None:
        run.folds = DEFAULT_FOLDS
        return
    run.folds = run.request.folds
    shortest = min(int((r.time_s >= (run.request.fit_from or 0.0) - 1e-9).sum()) for r in records)
    most = shortest // MIN_FOLD_ROWS - 1
    if run.folds > most:
        hint = f"give --folds {most} or fewer" if most >= 2 else "the record is too short"
        raise InputError(f"--folds {run.folds}: the shortest record has {shortest} rows, too "
                         f"few for {run.folds + 1} blocks of {MIN_FOLD_ROWS} rows; {hint}",
                         EX_USAGE)


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
    if run.request.fit_from is not None:
        prov["calibrated_from_s"] = run.request.fit_from
    if run.request.fit_until is not None:
        prov["calibrated_until_s"] = run.request.fit_until
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


def _read_records(paths: list[str], request: FitRequest, channels: set[str],
                  first: Record | None = None) -> list[Record]:
    """Read and check records; all must share `first`'s (or the first one's) period."""
    import math

    from compd.offline.channel_kind import ChannelKind, channel_kind, is_rate_channel
    from compd.offline.records import RecordError, check_units, read_record

    records: list[Record] = []
    for p in paths:
        r = read_record(p)
        if request.positions:  # the line through the positions: value or slope
            from compd.offline.position_record import line_record

            r = line_record(r, request.reference_position_mm, request.output)
        wanted = [request.output, *sorted(channels), *([request.switch] if request.switch else [])]
        r.require(wanted)
        temps = sorted(c for c in channels if not is_rate_channel(c))
        check_units(r, temps if request.kind != "greybox" else [], request.output)
        # (--candidates keeps every column: it chooses among them, and the hedge's
        # textbook and other members may read inputs the choice left out; a --fixed
        # term reads its own channels)
        if channels and not request.fixed and not request.candidates:
            # and the speeds, of which speed_warnings speaks
            r = _only_columns(r, {*wanted, *(c for c in r.columns
                                             if channel_kind(c) is ChannelKind.SPEED)})
        records.append(r)
        ref = first if first is not None else records[0]
        if not math.isclose(r.period_s, ref.period_s, rel_tol=1e-6):
            raise RecordError(f"{r.path}: sampled every {r.period_s:g} s but {ref.path} "
                              f"every {ref.period_s:g} s; records fitted together "
                              "need one sample period")
    return records


def _only_columns(record: Record, names: set[str]) -> Record:
    """`record` with only the columns `names` (and its time), copied so that the rest
    of the block the reader parsed is freed: a month at 1 s is 21 MB a column."""
    import dataclasses

    return dataclasses.replace(record, time_s=record.time_s.copy(),
                               columns={k: v.copy() for k, v in record.columns.items()
                                        if k in names})


def _calibration_rows(run: FitRun, records: list[Record]) -> list[Record]:
    """--until: each record up to that time (the model is causal: nothing after it
    changes what it predicts before, so the rows after are cut, not masked);
    --from: ``run.fit_window``, the rows each loss may count (the rows before run
    through the model from the record's start). InputError (64) naming the flag."""
    import dataclasses

    import numpy as np

    from compd.infiles import InputError
    from compd.sysexits import EX_USAGE

    start, until = run.request.fit_from, run.request.fit_until
    run.fit_window = None
    if start is None and until is None:
        return records
    if until is not None and start is not None and until < start:
        raise InputError(f"--until {until:g} s is before --from {start:g} s", EX_USAGE)
    if start and (run.request.kind != "tf" or run.request.structure == "search"):
        raise InputError("--from goes with --kind tf, without --structure search (the "
                         "greedy order search masks no rows)", EX_USAGE)
    out: list[Record] = []
    for whole in records:
        r = whole
        if until is not None:
            n = int(np.searchsorted(whole.time_s, until + 1e-9, side="right"))
            r = dataclasses.replace(whole, time_s=whole.time_s[:n],
                                    columns={k: v[:n] for k, v in whole.columns.items()})
        first = int(np.searchsorted(r.time_s, (start or 0.0) - 1e-9))
        if len(r) - first < 2 * MIN_FOLD_ROWS:
            span = f"0 … {r.time_s[-1]:g} s" if len(r) else "nothing"
            window = f"--from {start or 0.0:g} s --until {math.inf if until is None else until:g} s"
            raise InputError(f"{window}: {r.path} has {max(0, len(r) - first)} rows there (it "
                             f"spans {span}); at least {2 * MIN_FOLD_ROWS} needed", EX_USAGE)
        out.append(r)
    if start:
        run.fit_window = np.concatenate([r.time_s >= start - 1e-9 for r in out])
    return out


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


def fit_model(request: FitRequest) -> FitResult:
    """The model `request` asks for, identified from its records (warnings on
    stderr); ModelError, RecordError or InputError when it cannot be."""
    from compd.offline.records import speed_warnings
    from models.compensation import CompensationModel

    run = FitRun.of(request)
    specs = term_specs(request)
    data = list(request.data)
    channels = {ch for _, inputs in specs for ch in inputs}
    records = _calibration_rows(run, _read_records(data, request, channels))
    _check_folds(run, records)
    if sum(len(r) for r in records) > LONG_RECORD_ROWS:
        _return_freed_arrays()
    if request.candidates:
        specs = _search_specs(run, records)
        channels = {ch for _, inputs in specs for ch in inputs}
        records = _calibration_rows(run, _read_records(data, request, channels))
    holdout = _read_records(list(request.validation_record), request, channels, records[0])
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
    gate(model, request.force)  # compd check's warnings: nothing written without --force
    fallbacks = None
    if not request.no_fallbacks:  # a model for the loss of each input, in the same file
        from compd.offline.fit_fallback import fit_fallbacks

        reads = {ch for t in terms for ch in t.inputs}
        fallbacks = fit_fallbacks(run, records, ys, specs, holdout, fixed, reads)
        model.fallbacks = fallbacks.models
    return FitResult(model, info, records, fallbacks, run.search_table, run.search_chosen,
                     run.heldout_residuals)


#: arrays at least this large are mapped on their own and given back on free (a
#: month's columns at 1 s are 21 MB; the identification's blocks, a few MB, stay on
#: the heap and are reused: at 1 MB the month spent 99 s more in the kernel)
MMAP_THRESHOLD_BYTES = 8 << 20
#: ... for records longer than this (a day's arrays are 0.7 MB and its one block
#: 17 MB: mapped afresh each time, a day at 1 s spent 7 s more in the kernel)
LONG_RECORD_ROWS = 1 << 17


def _return_freed_arrays() -> None:
    """glibc's malloc raises its mmap threshold each time a mapped block is freed
    (up to 32 MB): a month's 21 MB columns then come from the heap, and once freed
    stay in the process's resident memory beside what comes next (a month at 1 s
    peaked at 512-522 MB, 493 MB with this). A fixed threshold (mallopt
    M_MMAP_THRESHOLD) gives them back. Nothing where there is no glibc."""
    import ctypes
    import ctypes.util

    name = ctypes.util.find_library("c")
    if not name:
        return
    try:
        ctypes.CDLL(name).mallopt(-3, MMAP_THRESHOLD_BYTES)  # M_MMAP_THRESHOLD
    except (OSError, AttributeError):
        return


def suggest_adaptation(fit: FitResult, request: FitRequest, measured: list[Any],
                       simulated: list[Any], period_s: float) -> dict[str, Any]:
    """`request.adaptation`'s learnt settings from the residual of `measured` less
    `simulated` and `fit`'s held-out residuals ({} without it, or with a warning
    when the records are too short for the lag: the model is written all the same)."""
    if not request.adaptation:
        return {}
    from compd.offline.probes import suggest_settings

    residuals = [m - s for m, s in zip(measured, simulated, strict=True)]
    try:
        return suggest_settings(residuals, period_s, request.adaptation_lag_s,
                                fit.heldout_residuals).as_dict()
    except ValueError as exc:
        print(f"compd fit: warning: --adaptation: {exc}; no settings suggested",
              file=sys.stderr)
        return {}
