"""`compd replay VALUE DATA --slope-model SLOPE [--reference-position-mm MM]`: the
error at every measured position of a record (columns ``dx_at_<x>mm_um``)
before and after the line that the value model and the slope model predict
(`compd.offline.position_replay`), per position and over all of them.

Each model is stepped over the record as `compd replay` steps one (``--init``;
``--score-from`` and ``--score-until`` as there); the value model's measured
series is the value at the reference position of the line through each row's
positions, the slope model's its slope, as `compd fit --positions` fitted
them. A record without two position columns, a model fitted for the other
half of the line, reference positions that disagree, a model of another
period or one whose inputs the record lacks: one line on stderr and exit 65.
--column, --config, --plot and the probe options go without --slope-model
(exit 64).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import TYPE_CHECKING

from compd.argtypes import number
from compd.sysexits import EX_DATAERR, EX_USAGE

if TYPE_CHECKING:
    from compd.offline.model_replay import InitMode
    from compd.offline.position_replay import PositionScore
    from compd.offline.records import Record


def add_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("a line along an axis (a record measured at several "
                                      "positions)")
    group.add_argument("--slope-model", metavar="SLOPE", default=None,
                       help="MODEL is the value model and SLOPE the slope model (compd fit "
                            "--positions --column value_um / slope_um_m): the error at every "
                            "dx_at_<x>mm_um column before and after their line")
    group.add_argument("--reference-position-mm", type=number(-1e5, 1e5), default=None,
                       metavar="MM",
                       help="with --slope-model: where the value applies (default: what the "
                            "models were fitted with, else 0)")


def _problem(args: argparse.Namespace) -> str | None:
    if args.slope_model is None:
        return "--reference-position-mm goes with --slope-model"
    for option, given in (("--column", args.output is not None),
                          ("--config", args.config is not None),
                          ("--plot", args.plot is not None),
                          ("--probe-every-min", args.probe_every_min is not None)):
        if given:
            return (f"{option} goes without --slope-model (the record's dx_at_<x>mm_um "
                    f"columns are scored against the models' line)")
    if args.score_until is not None and args.score_until < args.score_from:
        return (f"--score-until {args.score_until:g} s is before --score-from "
                f"{args.score_from:g} s")
    return None


def _rows(record: Record, score_from: float, score_until: float | None) -> slice:
    """The rows scored, as `compd replay` picks them; RecordError when none."""
    import numpy as np

    from compd.offline.records import RecordError

    first = int(np.searchsorted(record.time_s, score_from - 1e-9))
    if not (math.isfinite(score_from) and 0 <= first < len(record)):
        raise RecordError(f"--score-from {score_from:g} s: the record spans 0 … "
                          f"{record.time_s[-1]:g} s")
    last = len(record) if score_until is None else \
        int(np.searchsorted(record.time_s, score_until + 1e-9, side="right"))
    if last <= first:
        raise RecordError(f"--score-until {score_until:g} s: no sample from --score-from "
                          f"{score_from:g} s up to it")
    return slice(first, last)


def run(args: argparse.Namespace) -> int:
    from compd.infiles import load_model
    from compd.offline.model_replay import replay_with_init
    from compd.offline.position_record import (
        SLOPE_COLUMN,
        VALUE_COLUMN,
        read_position_record,
        with_line_columns,
    )
    from compd.offline.position_replay import check_line_models, score
    from compd.offline.records import RecordError
    from models.errors import ModelError

    problem = _problem(args)
    if problem:
        print(f"compd replay: {problem}", file=sys.stderr)
        return EX_USAGE
    init: InitMode = args.init or "estimate"
    try:
        value_model = load_model(args.model)
        slope_model = load_model(args.slope_model)
        pr = read_position_record(args.data)
        x0, source = check_line_models(value_model, slope_model, args.reference_position_mm,
                                      names=(args.model, args.slope_model))
        line = with_line_columns(pr.record, x0)
        value = replay_with_init(value_model, line, line.column(VALUE_COLUMN), init)
        slope = replay_with_init(slope_model, line, line.column(SLOPE_COLUMN), init)
        rows = _rows(pr.record, args.score_from, args.score_until)
        result = score(pr, value, slope, x0, rows)
    except (RecordError, ModelError) as exc:
        print(f"compd replay: {exc}", file=sys.stderr)
        return EX_DATAERR
    record = pr.record
    if args.json:
        print(json.dumps({**result.as_dict(), "reference_position_mm": x0,
                          "reference_from": source, "init": init}))
        return 0
    until = f" to {record.time_s[rows.stop - 1]:g} s" if args.score_until is not None else ""
    print(f"{args.model} (value) + {args.slope_model} (slope) on {record.path} "
          f"({len(record)} samples, {record.period_s:g} s; init {init}; reference position "
          f"{x0:g} mm, {_said(source)}; scored {result.scored_samples} from "
          f"{record.time_s[rows.start]:g} s{until})")
    print("\n".join(lines(result)))
    return 0


def _said(source: str) -> str:
    return {"models": "as the models were fitted", "asked": "as asked",
            "default": "the default: the models do not say"}[source]


def lines(result: PositionScore) -> list[str]:
    """The table: MAE / RMS (µm) before and after at each position, over all of
    them, and the position-dependent part."""
    out = [f"  {'position':>12}  {'before MAE / RMS':>18}  {'after MAE / RMS':>18}  (µm)"]
    for x, b, a in zip(result.positions_mm, result.before, result.after, strict=True):
        out.append(f"  {x:>9g} mm  {b.mae_um:>8.3f} / {b.rms_um:<7.3f}  "
                   f"{a.mae_um:>8.3f} / {a.rms_um:.3f}")
    b, a = result.overall_before, result.overall_after
    out.append(f"  {'all':>12}  {b.mae_um:>8.3f} / {b.rms_um:<7.3f}  "
               f"{a.mae_um:>8.3f} / {a.rms_um:.3f}")
    dep_b, dep_a = result.dependent_before_rms_um, result.dependent_after_rms_um
    share = f" ({(1.0 - dep_a / dep_b) * 100.0:.1f} % removed)" if dep_b > 0.0 else ""
    out.append(f"  position-dependent part, RMS: before {dep_b:.3f} µm, after "
               f"{dep_a:.3f} µm{share}")
    return out
