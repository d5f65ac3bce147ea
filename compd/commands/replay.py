"""`compd replay MODEL DATA --output dz_um [--plot out.png] [--json]`

Runs the model over a recorded run exactly as the daemon steps it (the same
`CompensationModel.set_references` at the first sample, then `step(sample)`
once per row) and reports fit %, residue min/max, Δpk and range reduction
(docs/models.md §11). A model whose sample period differs from the record's is
refused: its coefficients would mean something else.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import TYPE_CHECKING

from compd.sysexits import EX_DATAERR

if TYPE_CHECKING:
    import numpy as np
    import numpy.typing as npt

    from compd.offline.records import Record
    from models.compensation import CompensationModel

HELP = "run a model over a recorded run offline: fit %, residue, Δpk, range reduction, a plot"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", metavar="MODEL", help="model file, or a library name (sp2)")
    parser.add_argument("data", metavar="DATA",
                        help="calibration/verification record (CSV, or a compd recorder .db)")
    parser.add_argument("--output", required=True, metavar="COLUMN",
                        help="the measured displacement column (µm)")
    parser.add_argument("--plot", metavar="PNG", default=None,
                        help="write a figure: inputs above, measured/simulated/residue below")
    parser.add_argument("--force", action="store_true", help="replace an existing --plot file")
    parser.add_argument("--json", action="store_true", help="print the figures as one JSON line")


def replay_model(model: CompensationModel, record: Record) -> npt.NDArray[np.float64]:
    """δZ predicted at every row, stepping the model as the daemon does."""
    import numpy as np

    from compd.offline.records import RecordError

    if not math.isclose(model.period_s, record.period_s, rel_tol=1e-6):
        raise RecordError(f"{record.path}: sampled every {record.period_s:g} s but the model "
                          f"{model.name!r} was identified at {model.period_s:g} s; its "
                          "coefficients do not apply (refit it at this period)")
    record.require(model.channels)
    samples = record.samples()
    model.reset()
    model.set_references(samples[0])
    step = model.step
    return np.fromiter((step(s) for s in samples), dtype=np.float64, count=len(samples))


def plot_inputs(model: CompensationModel, record: Record) -> dict[str, npt.NDArray[np.float64]]:
    """The channels a replay figure shows above the displacement."""
    names = [c for c in record.columns if c in model.channels]
    names += [c for c in record.columns if "speed" in c.lower() and c not in names]
    return {c: record.columns[c] for c in names}


def run(args: argparse.Namespace) -> int:
    from compd.infiles import load_model
    from compd.offline.quality_check import checked_quality
    from compd.offline.records import RecordError, check_units, read_record
    from compd.outfiles import check_figure, write_atomically
    from models.errors import ModelError

    if args.plot is not None:
        check_figure(args.plot, force=args.force, inputs=[args.model, args.data])
    try:
        model = load_model(args.model)
        record = read_record(args.data)
        record.require([args.output])
        check_units(record, sorted(model.reference_channels), args.output)
        simulated = replay_model(model, record)
    except (RecordError, ModelError) as exc:
        print(f"compd replay: {exc}", file=sys.stderr)
        return EX_DATAERR
    measured = record.columns[args.output]
    try:
        q = checked_quality(measured, simulated, record.path, args.output)
    except RecordError as exc:
        print(f"compd replay: {exc}", file=sys.stderr)
        return EX_DATAERR
    if args.plot:
        from compd.offline.plots import replay_figure

        write_atomically(args.plot, lambda tmp: replay_figure(
                      tmp, record.time_s, plot_inputs(model, record), measured, simulated,
                      title=f"{model.name} on {record.path}", fit_pct=q.fit_percent,
                      dpk_um=q.dpk_um), "figure", force=args.force,
                         inputs=[args.model, args.data])
    if args.json:
        print(json.dumps(q.as_dict()))
    else:
        print(f"{model.name} on {record.path} ({len(record)} samples, {record.period_s:g} s)")
        print(f"  fit {q.fit_percent:.2f} %, residue {q.residue_min_um:.3f} … "
              f"{q.residue_max_um:.3f} µm, Δpk {q.dpk_um:.3f} µm, range reduction "
              f"{q.range_reduction:.2f}-fold")
        if args.plot:
            print(f"  figure: {args.plot}")
    return 0
