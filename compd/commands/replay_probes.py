"""`compd replay … --probe-every-min MINUTES`: the options of adaptation offline,
the request they make (`compd.offline.probe_replay.ProbeRequest`: the replay is
library code there) and its report.

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
from typing import TYPE_CHECKING, Any

from compd.argtypes import number, seed

if TYPE_CHECKING:
    import numpy as np
    import numpy.typing as npt

    from compd.offline.probe_replay import ProbeRequest
    from compd.offline.probes import ProbeRun
    from models.adaptation import AdaptationParams
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
    from compd.offline.probe_replay import probe_params

    if args.probe_every_min is not None:
        try:
            probe_params(probe_request(args))
        except ValueError as exc:
            return f"adaptation settings: {exc}"
        return ""
    given = [o for o, _, _, _ in _SETTINGS if getattr(args, _dest(o)) is not None]
    given += [o for o, v in (("--probe-noise-um", args.probe_noise_um),
                             ("--probe-seed", args.probe_seed), ("--gains", args.gains),
                             ("--adaptation-defaults", args.adaptation_defaults)) if v]
    return f"{', '.join(given)} need(s) --probe-every-min" if given else ""


def probe_request(args: argparse.Namespace) -> ProbeRequest:
    """The probe replay `args` ask for (``--probe-every-min`` given)."""
    from compd.offline.probe_replay import ProbeRequest

    return ProbeRequest(
        every_min=args.probe_every_min, noise_um=args.probe_noise_um, seed=args.probe_seed,
        gains=args.gains, defaults_only=args.adaptation_defaults,
        settings=tuple((f, getattr(args, _dest(o))) for o, f, _, _ in _SETTINGS
                       if getattr(args, _dest(o)) is not None),
        init=args.init or "estimate", output=args.output)


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


def plot_extras(run: ProbeRun | None, time_s: FloatArray) -> dict[str, Any]:
    """`replay_figure`'s keyword arguments for the adapted line and the probe points."""
    if run is None:
        return {}
    return {"adapted": run.adapted, "probes": (time_s[run.rows], run.values, run.accepted)}
