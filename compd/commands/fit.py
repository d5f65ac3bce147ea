"""`compd fit DATA [DATA…] --column dz_um --term bearing --term ambient [...]`

Identifies a compensation model from calibration records and writes a model
file (docs/models.md §2, §5, §6). Several records (e.g. a heat-up/cool-down and an
environmental run) are fitted jointly as separate experiments: each has its
own first sample as the reference, and the simulation restarts per record.
Held-out records (``--validation-record``) replace the folds for the choice.
Every pole is kept
within the slowest allowed time constant (``--max-time-constant-days``,
default 3) in the output-error fit and checked again before writing; a DC
gain absurd for the data is refused (`models.identify.checks`).

- ``--kind tf`` (default): the structure is chosen by forward validation
  (``--folds``, `models.identify.structures`): each candidate is trained on
  the rows before a held-out block, run from the record's start
  (initial conditions estimated when the records start warm) and scored on
  the block; candidates are the ARX least-squares baseline, one shared
  denominator refined by output error, ridge on the gains over it, and one
  denominator per term (the papers'); the simplest within 0.5 point of the
  best wins, and the table is printed. How stable that choice is against the
  other candidates and the textbook ARX(2,3) (`compd.offline.fit_hedge`) is
  printed and written in the provenance; when it is not stable, the leading
  candidates are averaged into the model written. ``--structure`` forces one (a forced
  structure below the ARX baseline is said); ``--structure search`` is the
  greedy per-term order search (`models.identify.tf_fit`). Orders
  ``--orders 2-4`` (`DEFAULT_ORDERS`): numerator lengths and denominator orders. One term per
  ``--term`` (a channel or a signed combination, ``bearing-column``,
  optionally named ``spindle=bearing-column``), or ``--candidates PATTERN
  --max-terms N``: the inputs chosen by validation (`compd.offline.fit_search`);
  speed and power channels enter absolute, temperatures relative.
- ``--kind greybox --term power_kw [--switch moving]`` and
  ``--kind mbotv --term bearing-column``: bounded least squares (one term).
- the last word (`compd.offline.fit_judge`): compd's choice, the textbook
  ARX(2,3) and no model judged on inner held-out blocks of the calibration
  rows cut by the spindle speed (interior cycles, cool-downs, the end:
  `compd.offline.fit_blocks`); a choice worse than no compensation on an
  interior cycle or cool-down gives way to the textbook (the end judges only
  the textbook), and nothing is written when the textbook is worse too
  (exit 65, unless ``--force``).
- fallbacks: for each input, a model on the others fitted the same way
  (`compd.commands.fit_fallback`), written as the model file's
  ``[[fallback]]`` tables; ``--no-fallbacks`` writes none.
- ``--fixed model.toml:ambient`` keeps an already-calibrated term: its
  prediction is subtracted before fitting, and it is copied into the output.

Every fitted term is rebuilt exactly as the file will hold it (repr floats),
checked for stability, its DC gain and sensitivity reported, and the written
file is replayed through the daemon's code path for the final figures (its
initial state estimated as `compd replay` does). Warnings (stderr): terms
that cancel each other on correlated inputs (`models.diagnostics`), a record
without a cool-down or speed steps.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path
from typing import Any, get_args

from compd.argtypes import RenamedOption, count, number
from compd.offline.fit_request import (
    DEFAULT_FOLDS,
    DEFAULT_MAX_TIME_CONSTANT_DAYS,
    DEFAULT_ORDERS,
    MIN_FOLD_ROWS,
    FitRequest,
    Structure,
)
from compd.sysexits import EX_DATAERR, EX_USAGE

HELP = "identify a compensation model from a calibration record and write a model file"



def parse_orders(text: str) -> tuple[int, int]:
    try:
        lo_s, _, hi_s = text.partition("-")
        lo = int(lo_s)
        hi = int(hi_s) if hi_s else lo
    except ValueError:
        raise argparse.ArgumentTypeError(f"orders must look like 1-4, got {text!r}") from None
    if not 1 <= lo <= hi <= 8:
        raise argparse.ArgumentTypeError(f"orders must satisfy 1 <= lo <= hi <= 8, got {text!r}")
    return lo, hi


#: --structure values
STRUCTURE_CHOICES: tuple[str, ...] = get_args(Structure)

#: the most cross-validation folds that make sense (each fold is one more
#: identification: --folds 100000 ran for minutes)
MAX_FOLDS = 20
#: at most this many inputs chosen by --candidates (each one more greedy round; the
#: columns they may match: `compd.offline.fit_search.MAX_CANDIDATES`)
MAX_TERMS = 12

#: the columns --positions offers: the line's value at the reference position and its
#: slope (`compd.offline.position_record`; literal here: the parser imports no numerics)
POSITIONS_COLUMNS = ("value_um", "slope_um_m")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("data", metavar="DATA", nargs="+",
                        help="calibration record(s) (CSV, or a compd recorder .db); several "
                             "are fitted jointly as separate experiments")
    parser.add_argument("--column", "--output", dest="output", required=True,
                        metavar="COLUMN", action=RenamedOption,
                        help="the measured displacement column (µm); --output is its "
                             "deprecated spelling")
    parser.add_argument("--positions", action="store_true",
                        help="the record measures the displacement at several positions "
                             "(columns dx_at_<x>mm_um): fit --column value_um (the value at "
                             "--reference-position-mm) or --column slope_um_m (µm/m) of the "
                             "line through each row's positions (docs/calibration.md)")
    parser.add_argument("--reference-position-mm", type=number(-1e5, 1e5), default=0.0,
                        metavar="MM", help="with --positions: the position the value is "
                        "taken at, e.g. the screw's fixed bearing (default 0)")
    parser.add_argument("--term", action="append", default=[], metavar="[NAME=]EXPR",
                        help="a term's input: a channel or e.g. bearing-column (repeatable)")
    parser.add_argument("--candidates", action="append", default=[], metavar="PATTERN",
                        help="choose the inputs by validation among the columns matching "
                             "these shell patterns (repeatable; e.g. 't*_degC', spindle_rpm); "
                             "speed/power columns enter absolute, temperatures relative")
    parser.add_argument("--max-terms", type=count(1, MAX_TERMS), default=3, metavar="N",
                        help=f"at most N inputs chosen with --candidates, 1 … {MAX_TERMS} "
                             "(default 3)")
    parser.add_argument("--kind", choices=("tf", "greybox", "mbotv"), default="tf",
                        help="model structure: tf transfer functions (ARX + output error), "
                             "greybox first-order ODEs, mbotv (default tf)")
    parser.add_argument("--structure", choices=STRUCTURE_CHOICES, default="auto",
                        help="tf structure: auto (default: chosen by forward validation "
                             "among arx, shared-oe, ridge, per-term-oe), one of those, or "
                             "search (the greedy per-term output-error order search)")
    parser.add_argument("--folds", type=count(2, MAX_FOLDS), default=None, metavar="K",
                        help="cross-validation folds: each record in K + 1 blocks, the first "
                             f"always training, 2 … {MAX_FOLDS}, each block at least "
                             f"{MIN_FOLD_ROWS} rows long (default {DEFAULT_FOLDS})")
    parser.add_argument("--orders", type=parse_orders, default=DEFAULT_ORDERS, metavar="LO-HI",
                        help="numerator lengths and denominator orders to try (default "
                             f"{DEFAULT_ORDERS[0]}-{DEFAULT_ORDERS[1]}; first order and static "
                             "remain the fallback when none of them is plausible)")
    parser.add_argument("--switch", metavar="CHANNEL", default=None,
                        help="grey-box u2 switch channel (1 = moving, 0 = standstill)")
    parser.add_argument("--fixed", action="append", default=[], metavar="MODEL:TERM",
                        help="keep an already-calibrated term, subtracted before fitting")
    parser.add_argument("--validation", type=number(0.05, 0.95), default=0.3,
                        help="--structure search: fraction of each record held out to choose "
                             "orders, 0.05 … 0.95 (default 0.3)")
    parser.add_argument("--validation-record", action="append", default=[], metavar="DATA",
                        help="a record used only to choose the orders (repeatable); the fit "
                             "then uses every DATA record whole")
    parser.add_argument("--max-time-constant-days", type=number(0.0, 3650.0, lo_open=True),
                        default=DEFAULT_MAX_TIME_CONSTANT_DAYS, metavar="DAYS",
                        help="slowest allowed pole, as a time constant in days (default "
                             f"{DEFAULT_MAX_TIME_CONSTANT_DAYS:g})")
    parser.add_argument("--from", dest="fit_from", type=number(0.0, 1e9), default=None,
                        metavar="SECONDS",
                        help="calibrate on the rows from this time on (as replay "
                             "--score-from): the rows before still run through the model "
                             "from the record's start, outside every loss")
    parser.add_argument("--until", dest="fit_until", type=number(0.0, 1e9), default=None,
                        metavar="SECONDS",
                        help="calibrate on the rows up to this time (inclusive, as replay "
                             "--score-until); the rows after are not read")
    parser.add_argument("-o", dest="model_file", metavar="MODEL.toml", default=None,
                        help="model file to write (required: nothing is written beside the "
                             "records, which may be a shared or read-only data folder)")
    parser.add_argument("--force", action="store_true",
                        help="replace an existing model file (never one of the inputs), and "
                             "write a model whose error on held-out rows exceeds the "
                             "displacement")
    parser.add_argument("--name", default=None, help="model name (default: from DATA)")
    parser.add_argument("--json", action="store_true", help="print the result as one JSON line")
    parser.add_argument("--adaptation", action="store_true",
                        help="also learn the probe estimator's settings from the fitted model's "
                             "residual (compd.offline.probes) and write them into the model "
                             "file's [adaptation] table (without them, the file says why and "
                             "adaptation starts stood down: docs/adaptation.md §2)")
    parser.add_argument("--no-fallbacks", action="store_true",
                        help="write no fallback models (by default one per input, fitted "
                             "the same way without it, used while that sensor is invalid)")
    parser.add_argument("--adaptation-lag-s", type=number(0.0, 1e7, lo_open=True),
                        default=7200.0, metavar="SECONDS",
                        help="with --adaptation: the probe interval the drift is measured over "
                             "(default 7200: give your probe spacing)")


def fit_request(args: argparse.Namespace) -> FitRequest:
    """The fit `args` ask for (`add_arguments`' options, each a field of the same name)."""
    argv_is_fit = sys.argv[1:2] == ["fit"]  # compd fit …, not a test calling `run`
    return FitRequest(
        data=tuple(str(p) for p in args.data), output=args.output, term=tuple(args.term),
        candidates=tuple(args.candidates), max_terms=args.max_terms, kind=args.kind,
        structure=args.structure, folds=args.folds, orders=args.orders, switch=args.switch,
        fixed=tuple(args.fixed), validation=args.validation,
        validation_record=tuple(args.validation_record),
        max_time_constant_days=args.max_time_constant_days, fit_from=args.fit_from,
        fit_until=args.fit_until, positions=args.positions,
        reference_position_mm=args.reference_position_mm, force=args.force, name=args.name,
        json=args.json, adaptation=args.adaptation, adaptation_lag_s=args.adaptation_lag_s,
        no_fallbacks=args.no_fallbacks,
        command_line=shlex.join(["compd", *sys.argv[1:]]) if argv_is_fit else None)


def run(args: argparse.Namespace) -> int:
    import os

    # the identification's matrices are small (tens of columns): BLAS threads
    # only contend for the cores (a day at 1 s: 10.8 s threaded, 7.5 s not)
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    import numpy as np

    if args.model_file is None:  # before any work: where the model goes is the user's say
        print("compd fit: -o MODEL.toml is required (where to write the model; nothing is "
              "written beside the records)", file=sys.stderr)
        return EX_USAGE
    if args.reference_position_mm and not args.positions:
        print("compd fit: --reference-position-mm applies with --positions", file=sys.stderr)
        return EX_USAGE
    if args.positions and args.output not in POSITIONS_COLUMNS:
        print(f"compd fit: --positions fits --column {' or '.join(POSITIONS_COLUMNS)} (the "
              f"value or the slope of the line along the axis), not {args.output!r}",
              file=sys.stderr)
        return EX_USAGE

    from compd.infiles import load_model
    from compd.offline.fit import (
        adaptation_provenance,
        fit_model,
        save_model,
        suggest_adaptation,
        term_specs,
    )
    from compd.offline.model_replay import replay_with_init
    from compd.offline.records import RecordError
    from compd.outfiles import check_output, write_atomically
    from compd.progress import terminal_status
    from models.errors import ModelError
    from models.quality import quality

    request = fit_request(args)
    status = terminal_status("compd fit", quiet=request.json)  # a terminal only
    try:
        status.stage("reading the records and identifying the model")
        term_specs(request)  # a term that does not parse is said before the output is checked
        sources = request.input_paths()
        out = check_output(args.model_file, "model file", force=request.force, inputs=sources)
        fit = fit_model(request)
        write_atomically(out, lambda tmp: save_model(fit.model, tmp, Path(request.data[0]).name),
                         "model file", force=request.force, inputs=sources)
        model = load_model(out)  # what the daemon will load
        records, info = fit.records, fit.info
        status.stage("replaying the model as the daemon steps it")
        simulated = [replay_with_init(model, r, r.column(request.output), "estimate")
                     for r in records]
    except (RecordError, ModelError) as exc:
        status.done()
        print(f"compd fit: {exc}", file=sys.stderr)
        return EX_DATAERR
    finally:
        status.done()
    # the figures and the residual over the calibration rows (--from: the rows before
    # ran through the model, outside the calibration)
    if request.fit_from is None:  # every row: the arrays themselves, not copies
        measured = [r.column(request.output) for r in records]
    else:
        keep = [r.time_s >= request.fit_from - 1e-9 for r in records]
        measured = [r.column(request.output)[k] for r, k in zip(records, keep, strict=True)]
        simulated = [s[k] for s, k in zip(simulated, keep, strict=True)]
    # the probe estimator's settings (--adaptation; without it fit_model marked the
    # model's table unproven and said why): where they cannot be learnt, the file says
    # why and its adaptation starts stood down
    adapt: dict[str, Any] = {}
    why_not: str | None = None
    if request.adaptation:
        from compd.offline.probes import Suggestion

        adapt, why_not = suggest_adaptation(fit, request, measured, simulated,
                                            records[0].period_s)
        model.adaptation = Suggestion(**adapt).settings() if adapt else {"unproven": True}
        model.provenance = {**model.provenance, **adaptation_provenance(adapt, why_not)}
        write_atomically(out, lambda tmp: save_model(model, tmp, Path(records[0].path).name),
                         "model file", force=True, inputs=[r.path for r in records])
    if why_not is not None:
        print(f"compd fit: warning: adaptation settings not learnt: {why_not}; the model "
              "file says so, and adaptation starts stood down on it", file=sys.stderr)
    per = [quality(m, s) for m, s in zip(measured, simulated, strict=True)]
    q = per[0] if len(records) == 1 else quality(np.concatenate(measured),
                                                 np.concatenate(simulated))
    fallbacks = fit.fallbacks
    fallback_figures = fallbacks.figures if fallbacks is not None else {}
    for note in fallbacks.notes if fallbacks is not None else ():
        print(f"compd fit: {note}", file=sys.stderr)
    if request.json:
        extra = {"subsets": fit.search_table} if fit.search_table else {}
        print(json.dumps({"terms": info, "fit_percent": q.fit_percent, "dpk_um": q.dpk_um, **extra,
                          **({"adaptation": adapt} if adapt else
                             {"adaptation_not_learnt": why_not} if why_not else {}),
                          "model_file": str(out),
                          "fallbacks": fallback_figures,
                          "records": [{"path": r.path, **pq.as_dict()}
                                      for r, pq in zip(records, per, strict=True)]}))
        return 0
    rows = "" if request.fit_from is None else f", calibrated on those from {request.fit_from:g} s"
    for r in records:
        print(f"compd fit: {len(r)} samples every {r.period_s:g} s from {r.path}{rows}")
    for t in info:
        if t["kind"] == "tf":
            print(f"  term {t['name']} {t['inputs']}: numerator length "
                  f"{t['orders']['numerator_length']}, denominator order "
                  f"{t['orders']['denominator_order']}; poles |p| "
                  + ", ".join(f"{p:.6f}" for p in t["poles"]))
            print(f"    {t['sensitivity']}")
        else:
            print(f"  term {t['name']} ({t['kind']}) {t['inputs']}: fit {t['fit_percent']:.2f} %")
    if fit.search_table:
        from compd.offline.fit_search import table_lines

        print("\n".join(table_lines(fit.search_table, fit.search_chosen)))
    if info and info[0]["kind"] == "tf" and "candidates" in info[0]["selection"]:
        from compd.offline.fit_hedge import stability_lines
        from compd.offline.fit_judge import verdict_lines
        from compd.offline.fit_select import selection_lines

        print("\n".join(selection_lines(info[0]["selection"])
                        + stability_lines(info[0]["selection"])
                        + verdict_lines(info[0]["selection"])))
    elif info and info[0]["kind"] == "tf":
        head = info[0]
        print(f"  ARX fit {head['arx_fit_percent']:.2f} %, output-error fit "
              f"{head['oe_fit_percent']:.2f} % (validation "
              f"{head['oe_validation_fit_percent']:.2f} %)")
    for r, pq in zip(records, per, strict=True) if len(records) > 1 else ():
        print(f"  on {r.path}: fit {pq.fit_percent:.2f} %, Δpk {pq.dpk_um:.3f} µm, range "
              f"reduction {pq.range_reduction:.2f}-fold")
    print(f"  model (replayed as the daemon steps it, initial state estimated): fit "
          f"{q.fit_percent:.2f} %, Δpk {q.dpk_um:.3f} µm, range reduction "
          f"{q.range_reduction:.2f}-fold")
    if adapt:
        print(f"  [adaptation] learnt from the residual (drift over {adapt['lag_s']:g} s, "
              f"measured on {adapt['drift_from']}): "
              f"probe_noise_um = {adapt['probe_noise_um']:.3g}, bias_rw_um_per_sqrt_h = "
              f"{adapt['bias_rw_um_per_sqrt_h']:.3g}, apply_sigma = {adapt['apply_sigma']:g}, "
              f"max_step_um = {adapt['max_step_um']:.3g}; written as the model's [adaptation] "
              "(see docs/adaptation.md §3)")
    for lost, fig in sorted(fallback_figures.items()):
        v = fig["validation_fit_percent"]
        print(f"  fallback without {lost}: {' + '.join(fig['inputs'])}"
              + (f", validation {v:.2f} %" if v is not None else ""))
    print(f"  wrote {out}")
    return 0


