"""`compd replay … --probe-every-min MINUTES`: the options of adaptation offline and
its report (the estimator `models.adaptation`, the run `compd.offline.probes`).

The plain figures stay as they are; beside them ``"adapted"`` (the same keys,
plus the probes used and refused and the final bias) and ``"crude"`` (the
residual of each probe held until the next: the textbook baseline, same run).
The estimator's settings are `[adaptation]`'s, as options; the defaults are
the model file's `[adaptation]` table (learnt by `compd fit --adaptation`)
over `models.adaptation.AdaptationParams`' (`--adaptation-defaults`: the
latter alone). The report counts the probes at which the estimator's score
made it stand down.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from compd.argtypes import number, seed

if TYPE_CHECKING:
    import numpy as np
    import numpy.typing as npt

    from compd.offline.probes import ProbeRun
    from compd.offline.records import Record
    from models.adaptation import AdaptationParams
    from models.compensation import CompensationModel
    from models.quality import CompensationFigures

    FloatArray = npt.NDArray[np.float64]

#: option -> AdaptationParams field, with the option's range
_SETTINGS: tuple[tuple[str, str, Any, str], ...] = (
    ("--bias-rw-um-per-sqrt-h", "bias_rw_um_per_sqrt_h", number(0.0, 1000.0),
     "bias random walk, µm/√h (default {:g})"),
    ("--probe-sigma-um", "probe_noise_um", number(0.0, 1000.0, lo_open=True),
     "the estimator's probe noise σ, µm (default: the model's [adaptation] value or {:g}; "
     "with --probe-noise-um > 0, that combined with the model's value, or alone)"),
    ("--gate-sigma", "gate_sigma", number(0.0, 1e6, lo_open=True),
     "refuse a probe whose innovation exceeds this many σ (default {:g})"),
    ("--max-step-um", "max_step_um", number(0.0, 1000.0, lo_open=True),
     "largest change of the correction per probe, µm (default {:g})"),
    ("--max-total-um", "max_total_um", number(0.0, 1000.0, lo_open=True),
     "largest |bias|, µm (default {:g})"),
    ("--gain-rw-per-sqrt-h", "gain_rw_per_sqrt_h", number(0.0, 10.0),
     "with --gains: each term's relative gain random walk, per √h (default {:g})"),
    ("--max-gain", "max_gain", number(0.0, 10.0, lo_open=True),
     "with --gains: largest relative gain correction (default {:g})"),
    ("--initial-gain-sigma", "initial_gain_sigma", number(0.0, 10.0),
     "with --gains: σ of each relative gain correction at the start (default {:g})"),
    ("--initial-bias-sigma-um", "initial_bias_sigma_um", number(0.0, 1000.0),
     "σ of the bias at the start, µm (default {:g})"),
    ("--apply-sigma", "apply_sigma", number(0.0, 1e6),
     "apply the estimate only when it departs from the applied correction by more than "
     "this many σ; 0 applies every accepted probe (default {:g})"),
    ("--score-window", "score_window", number(0.0, 1e4),
     "accepted probes the estimator's self-score spans; it stands down while adapting "
     "loses over them; 0 never stands down (default {:g})"),
    ("--reacquire-after", "reacquire_after", number(0.0, 1e4),
     "gate refusals in a row agreeing in direction after which the estimator re-acquires; "
     "0 never (default {:g})"),
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("adaptation offline (probes taken from --output)")
    group.add_argument("--probe-every-min", type=number(0.0, 1e9 / 60.0, lo_open=True),
                       default=None, metavar="MINUTES",
                       help="probe the measured column every this many minutes of the record "
                       "and report the figures with the estimator beside the plain ones (as "
                       "compd sim/plan --probe-every-min)")
    group.add_argument("--probe-every", type=number(0.0, 1e9, lo_open=True),
                       dest="probe_every_min", action=_SecondsAsMinutes, metavar="SECONDS",
                       help="deprecated: --probe-every-min in seconds")
    group.add_argument("--probe-noise-um", type=number(0.0, 1000.0), default=0.0,
                       metavar="X", help="seeded noise added to each probe value (default 0)")
    group.add_argument("--probe-seed", type=seed, default=0, help="seed of the probe noise")
    group.add_argument("--gains", action="store_true",
                       help="also estimate a slow gain correction of each term")
    group.add_argument("--adaptation-defaults", action="store_true",
                       help="ignore the model file's [adaptation] table (the settings "
                       "compd fit --adaptation learnt): the library's defaults")
    defaults = _defaults()
    for option, field, kind, text in _SETTINGS:
        group.add_argument(option, type=kind, default=None, metavar="X",
                           help=text.format(getattr(defaults, field)))


class _SecondsAsMinutes(argparse.Action):
    """The former ``--probe-every SECONDS``: stored as minutes, with one line on stderr
    naming the option that replaces it."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: object, option_string: str | None = None) -> None:
        import sys

        seconds = float(values)  # type: ignore[arg-type]  # argparse gives what type made
        print(f"{parser.prog}: --probe-every SECONDS is deprecated, use --probe-every-min "
              f"MINUTES (--probe-every {seconds:g} is --probe-every-min {seconds / 60.0:g})",
              file=sys.stderr)
        setattr(namespace, self.dest, seconds / 60.0)


def _dest(option: str) -> str:
    return option.lstrip("-").replace("-", "_")


def _defaults() -> AdaptationParams:
    from models.adaptation import AdaptationParams

    return AdaptationParams()


def usage_problem(args: argparse.Namespace) -> str:
    """Why the probe options cannot be used as given ("" when they can)."""
    if args.probe_every_min is not None:
        try:
            params_from_args(args)
        except ValueError as exc:
            return f"adaptation settings: {exc}"
        return ""
    given = [o for o, _, _, _ in _SETTINGS if getattr(args, _dest(o)) is not None]
    given += [o for o, v in (("--probe-noise-um", args.probe_noise_um),
                             ("--probe-seed", args.probe_seed), ("--gains", args.gains),
                             ("--adaptation-defaults", args.adaptation_defaults)) if v]
    return f"{', '.join(given)} need(s) --probe-every-min" if given else ""


def params_from_args(args: argparse.Namespace,
                     learnt: Mapping[str, Any] | None = None) -> AdaptationParams:
    """The estimator's settings: the options given over the model's learnt table (unless
    --adaptation-defaults) over the defaults (ValueError when bad)."""
    table = {} if args.adaptation_defaults or learnt is None else dict(learnt)
    changes: dict[str, Any] = {f: getattr(args, _dest(o)) for o, f, _, _ in _SETTINGS
                               if getattr(args, _dest(o)) is not None}
    if "probe_noise_um" not in changes and args.probe_noise_um > 0:
        # the probe's added noise, on top of what the model's own residual does fast
        changes["probe_noise_um"] = math.hypot(float(table.get("probe_noise_um", 0.0)),
                                               args.probe_noise_um)
    gains = {"gains": True} if args.gains else {}
    from models.adaptation import mark_unproven

    # as the daemon: settings not learnt for the model start stood down
    return dataclasses.replace(_defaults(), **{**mark_unproven(table), **gains, **changes})


def figures(run: ProbeRun, adapted: CompensationFigures, crude: CompensationFigures,
            first: int, params: AdaptationParams, rms: dict[str, float],
            args_defaults: bool = True) -> dict[str, Any]:
    """The JSON keys "adapted", "crude" and "adaptation" (the settings used); `rms`
    the residue's RMS (µm, scored rows) of "plain", "adapted" and "crude"."""
    scored = int((run.rows >= first).sum())
    return {
        "adapted": {**adapted.as_dict(), "probes": int(run.rows.size),
                    "probes_scored": scored, "probes_used": int(run.accepted.sum()),
                    "probes_refused": int((~run.accepted).sum()),
                    "applied_moves": run.adapter.applied_moves,
                    "stand_downs": run.adapter.stand_downs,
                    "standing_down": run.adapter.standing_down,
                    "bias_um": run.adapter.bias_um,
                    "estimated_bias_um": run.adapter.estimated_bias_um,
                    "bias_sigma_um": run.adapter.bias_sigma_um,
                    "residue_rms_um": rms["adapted"],
                    "plain_residue_rms_um": rms["plain"]},
        "crude": {**crude.as_dict(), "probes": int(run.rows.size),
                  "residue_rms_um": rms["crude"]},
        "adaptation": dataclasses.asdict(params),
        "adaptation_from": "defaults" if args_defaults else "model",
    }


def lines(plain: CompensationFigures, extra: dict[str, Any], every_min: float,
          noise_um: float) -> list[str]:
    """The text report's lines after the plain figures."""
    a, c = extra["adapted"], extra["crude"]

    def ratio(x: float) -> str:
        return f"{x / plain.range_reduction:.2f}x the plain model's"

    return [
        f"  adapted (a probe every {every_min:g} min, +{noise_um:g} µm noise; "
        f"{a['probes']} probes, {a['probes_used']} used, {a['probes_refused']} refused, applied at "
        f"{a['applied_moves']}, stood down {a['stand_downs']} time(s); settings from the "
        f"{extra['adaptation_from']}"
        + (", not learnt for this model: started stood down" if extra["adaptation"].get(
            "unproven") else "")
        + f"; bias applied {a['bias_um']:.3f} µm, estimated "
        f"{a['estimated_bias_um']:.3f} ± {a['bias_sigma_um']:.3f} µm):",
        f"    fit {a['fit_percent']:.2f} %, residue {a['residue_min_um']:.3f} … "
        f"{a['residue_max_um']:.3f} µm, RMS {a['residue_rms_um']:.3f} µm (plain "
        f"{a['plain_residue_rms_um']:.3f}), Δpk {a['dpk_um']:.3f} µm, range reduction "
        f"{a['range_reduction']:.2f}-fold ({ratio(a['range_reduction'])})",
        f"  crude (each probe's residual held until the next): fit {c['fit_percent']:.2f} %, "
        f"RMS {c['residue_rms_um']:.3f} µm, Δpk {c['dpk_um']:.3f} µm, range reduction "
        f"{c['range_reduction']:.2f}-fold ({ratio(c['range_reduction'])})",
    ]


def replay(args: argparse.Namespace, model: CompensationModel, record: Record,
           measured: FloatArray, simulated: FloatArray, first: int
           ) -> tuple[ProbeRun, dict[str, Any]]:
    """Run the probes over the replay; RecordError when the figures mean nothing."""
    import numpy as np

    from compd.offline.model_replay import replay_terms
    from compd.offline.probes import run_probes
    from compd.offline.quality_check import checked_quality

    every_s = 60.0 * args.probe_every_min
    if every_s < record.period_s:  # a probe at every row is the most there can be
        from compd.infiles import InputError
        from compd.sysexits import EX_USAGE

        raise InputError(f"--probe-every-min {args.probe_every_min:g}: shorter than the "
                         f"record's period of {record.period_s:g} s (at most one probe per "
                         "row)", EX_USAGE)
    params = params_from_args(args, model.adaptation)
    terms = None
    if params.gains:
        terms = replay_terms(model, record, steady=args.init == "steady")
    run = run_probes(simulated, measured, record.time_s, terms, every_s=every_s,
                     noise_um=args.probe_noise_um, seed=args.probe_seed, params=params)
    adapted = checked_quality(measured[first:], run.adapted[first:], record.path, args.output)
    crude = checked_quality(measured[first:], run.crude[first:], record.path, args.output)
    rms = {name: float(np.sqrt(np.mean((measured[first:] - pred[first:]) ** 2)))
           for name, pred in (("plain", simulated), ("adapted", run.adapted),
                              ("crude", run.crude))}
    return run, figures(run, adapted, crude, first, params, rms,
                        args.adaptation_defaults or not model.adaptation)


def plot_extras(run: ProbeRun | None, time_s: FloatArray) -> dict[str, Any]:
    """`replay_figure`'s keyword arguments for the adapted line and the probe points."""
    if run is None:
        return {}
    return {"adapted": run.adapted, "probes": (time_s[run.rows], run.values, run.accepted)}
