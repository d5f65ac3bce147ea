"""`compd replay MODEL DATA --output dz_um [--init estimate|steady|rest]
[--score-from SECONDS] [--score-until SECONDS] [--plot out.png] [--json]`

Runs the model over a recorded run (the same `CompensationModel.set_references`
at the first sample, then `step(sample)` once per row: the bare model, the
papers' figures) and reports fit %, the mean absolute and RMS residue (µm),
residue min/max, Δpk and range reduction (docs/models.md §11). With ``--config
CONFIG`` each row goes through the daemon's own cycle instead
(`compd.offline.cycle_replay`: that config's channel validation, fault policy,
clamp, slew limit and deadband, the model started as the daemon starts it), and
the figures are those of the offset the daemon would have put in force. A model whose sample
period differs from the record's is refused: its coefficients would mean
something else.

The model's starting state is said, never assumed silently (``--init``:
estimate, the default, steady or rest; `compd.offline.model_replay` says each,
and steps the model: this module is the command line around it).

``--score-from S`` runs the model from the record's start and scores only the
samples from S seconds on (what a daemon that has been running sees);
``--score-until U`` stops the scoring at U seconds (a block inside a record). The
daemon itself starts from its checkpoint, or at steady state (`compd.runtime.startup`).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import TYPE_CHECKING, Any

from compd.argtypes import RenamedOption, number
from compd.commands import replay_positions, replay_probes
from compd.offline.model_replay import INIT_MODES
from compd.sysexits import EX_DATAERR, EX_USAGE

if TYPE_CHECKING:
    import numpy as np
    import numpy.typing as npt

    from compd.offline.probes import ProbeRun
    from compd.offline.records import Record
    from models.compensation import CompensationModel

HELP = "run a model over a recorded run offline: fit %, residue, Δpk, range reduction, a plot"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", metavar="MODEL", help="model file, or a library name (sp2)")
    parser.add_argument("data", metavar="DATA",
                        help="calibration/verification record (CSV, or a compd recorder .db)")
    parser.add_argument("--column", "--output", dest="output", default=None,
                        metavar="COLUMN", action=RenamedOption,
                        help="the measured displacement column (µm; required unless "
                             "--slope-model); --output is its deprecated spelling")
    parser.add_argument("--plot", metavar="PNG", default=None,
                        help="write a figure: inputs above, measured/simulated/residue below")
    parser.add_argument("--force", action="store_true", help="replace an existing --plot file")
    parser.add_argument("--config", metavar="CONFIG", default=None,
                        help="through the daemon's own cycle with this config's validation, "
                             "fault policy and output stage: the offset it would have written")
    parser.add_argument("--init", choices=INIT_MODES, default=None,
                        help="the model's state at the first sample: estimate (default: "
                             "least squares on the first half of the record), steady, rest")
    parser.add_argument("--score-from", type=number(0.0, 1e9), default=0.0, metavar="SECONDS",
                        help="run from the record's start, score only from this time on")
    parser.add_argument("--score-until", type=number(0.0, 1e9), default=None,
                        metavar="SECONDS",
                        help="score only up to this time (inclusive; with --score-from: a "
                             "block inside the record)")
    parser.add_argument("--json", action="store_true", help="print the figures as one JSON line")
    replay_probes.add_arguments(parser)
    replay_positions.add_arguments(parser)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from compd.infiles import load_model
    from compd.offline.model_replay import plot_inputs, replay_with_init
    from compd.offline.quality_check import checked_quality
    from compd.offline.records import RecordError, check_units, read_record
    from compd.outfiles import check_figure, write_atomically
    from models.errors import ModelError

    if args.slope_model is not None or args.reference_position_mm is not None:
        return replay_positions.run(args)  # a line along an axis, scored at its positions
    if args.output is None:
        print("compd replay: --column COLUMN is required (the measured displacement; or "
              "--slope-model for a record measured at several positions)", file=sys.stderr)
        return EX_USAGE
    problem = replay_probes.usage_problem(args)
    if not problem and args.config is not None:
        if args.init is not None:
            problem = ("--init goes without --config (the daemon's cycle starts the model "
                       "as the daemon does)")
        elif args.probe_every_min is not None:
            problem = ("--probe-every-min goes without --config (the probes replay beside the "
                       "bare model)")
    args.init = args.init or "estimate"
    if not problem and args.score_until is not None and args.probe_every_min is not None:
        problem = "--score-until goes without --probe-every-min (the probes score to the end)"
    if not problem and args.score_until is not None and args.score_until < args.score_from:
        problem = (f"--score-until {args.score_until:g} s is before --score-from "
                   f"{args.score_from:g} s")
    if problem:
        print(f"compd replay: {problem}", file=sys.stderr)
        return EX_USAGE
    if args.plot is not None:
        check_figure(args.plot, force=args.force, inputs=[args.model, args.data])
    try:
        model = load_model(args.model)
        record = read_record(args.data)
        record.require([args.output])
        check_units(record, sorted(model.reference_channels), args.output)
        measured = record.columns[args.output]
        if args.config is not None:
            simulated = _through_the_cycle(args.config, model, record)
        else:
            simulated = replay_with_init(model, record, measured, args.init)
        first = int(np.searchsorted(record.time_s, args.score_from - 1e-9))
        if not (math.isfinite(args.score_from) and 0 <= first < len(record)):
            raise RecordError(f"--score-from {args.score_from:g} s: the record spans 0 … "
                              f"{record.time_s[-1]:g} s")
        last = len(record) if args.score_until is None else \
            int(np.searchsorted(record.time_s, args.score_until + 1e-9, side="right"))
        if last <= first:
            raise RecordError(f"--score-until {args.score_until:g} s: no sample from "
                              f"--score-from {args.score_from:g} s up to it (the record spans "
                              f"0 … {record.time_s[-1]:g} s)")
    except (RecordError, ModelError) as exc:
        print(f"compd replay: {exc}", file=sys.stderr)
        return EX_DATAERR
    probes: ProbeRun | None = None
    extra: dict[str, Any] = {}
    try:
        q = checked_quality(measured[first:last], simulated[first:last], record.path,
                            args.output)
        res = measured[first:last] - simulated[first:last]
        mae, rms = float(np.mean(np.abs(res))), float(np.sqrt(np.mean(res ** 2)))
        if args.probe_every_min is not None:
            from compd.offline.probe_replay import replay_probes as run_probe_replay

            probes, extra = run_probe_replay(replay_probes.probe_request(args), model, record,
                                             measured, simulated, first)
    except RecordError as exc:
        print(f"compd replay: {exc}", file=sys.stderr)
        return EX_DATAERR
    from models.diagnostics import flat_window

    flat = flat_window(measured[first:last], res)
    if flat is not None:
        print(f"compd replay: warning: {flat}", file=sys.stderr)
    if args.plot:
        from compd.offline.plots import replay_figure

        write_atomically(args.plot, lambda tmp: replay_figure(
                      tmp, record.time_s, plot_inputs(model, record), measured, simulated,
                      title=f"{model.name} on {record.path}", scored=(first, last),
                      **replay_probes.plot_extras(probes, record.time_s)),
                         "figure", force=args.force,
                         inputs=[args.model, args.data])
    if args.json:
        init = "daemon" if args.config is not None else args.init
        print(json.dumps({**q.as_dict(), "mae_um": mae, "rms_um": rms, "init": init,
                          "through": "cycle" if args.config is not None else "model",
                          "scored_samples": last - first, **extra}))
    else:
        until = f" to {record.time_s[last - 1]:g} s" if args.score_until is not None else ""
        print(f"{model.name} on {record.path} ({len(record)} samples, {record.period_s:g} s; "
              f"{_how(args)}; scored {last - first} from {record.time_s[first]:g} s"
              f"{until})")
        print(f"  fit {q.fit_percent:.2f} %, MAE {mae:.3f} µm, RMS {rms:.3f} µm, residue "
              f"{q.residue_min_um:.3f} … {q.residue_max_um:.3f} µm, Δpk {q.dpk_um:.3f} µm, "
              f"range reduction {q.range_reduction:.2f}-fold")
        if extra:
            print("\n".join(replay_probes.lines(q, extra, args.probe_every_min,
                                                 args.probe_noise_um)))
        if args.plot:
            print(f"  figure: {args.plot}")
    return 0


def _how(args: argparse.Namespace) -> str:
    if args.config is not None:
        return f"through the daemon's cycle with {args.config}"
    return f"init {args.init}"


def _through_the_cycle(config: str, model: CompensationModel, record: Record
                       ) -> npt.NDArray[np.float64]:
    """The offset the daemon's cycle puts in force at each row, with `config`'s
    validation, fault policy and output stage (`compd.offline.cycle_replay`);
    ConfigError (78) for a bad config, ModelError when `model` does not fit it (checked
    as the loader checks the config's own model), RecordError when the record does not."""
    from compd.config.loader import load_config, with_model
    from compd.core.params import params_from_config
    from compd.errors import ConfigError
    from compd.offline.cycle_replay import replay_cycle
    from compd.offline.model_replay import check_period
    from compd.offline.records import RecordError
    from models.errors import ModelError

    cfg = load_config(config)
    try:
        cfg = with_model(cfg, model)
    except ConfigError as exc:
        raise ModelError(f"the model {model.name!r} does not fit {config}: {exc.reason}"
                         ) from None
    params = params_from_config(cfg)
    if not math.isclose(params.period_s, record.period_s, rel_tol=1e-6):
        raise RecordError(f"{record.path}: sampled every {record.period_s:g} s but {config} "
                          f"runs its cycle every {params.period_s:g} s")
    check_period(model, record)
    missing = sorted(set(params.channels) - set(record.columns))
    if missing:
        raise RecordError(f"{record.path}: no column(s) {missing} for the channels {config} "
                          "validates")
    return replay_cycle(params, cfg.model, record).offset_um
