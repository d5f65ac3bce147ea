"""`compd step MODEL [--plot out.png] [--hours H] [--json]`

The response of each term to a unit step of its input (1 K for temperature
terms, 1 unit of the channel for a grey-box power/speed input) from rest,
stepped with the model's own filters at its sample period, like the papers'
LTI step-response figures. Without --hours the span covers five times the
slowest time constant (at most two days: then it says the span was capped).
Each term prints the value at the span's end, labelled with its time, and
the DC gain (the steady state, µm per unit of the input: µm/K, µm/rpm), with
the share of it reached. The figure draws every term of one input unit on one
axis, so that terms that oppose are seen to.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import TYPE_CHECKING

from compd.argtypes import number
from compd.sysexits import EX_DATAERR

if TYPE_CHECKING:
    import numpy as np
    import numpy.typing as npt

    from models.compensation import CompensationModel

    FloatArray = npt.NDArray[np.float64]

HELP = "step response of each term of a model (1 K step), as numbers and a plot"

#: a step response longer than this many samples is refused (memory, time)
MAX_STEP_SAMPLES = 5_000_000
#: the longest span chosen without --hours (five time constants, at most this)
MAX_AUTO_SPAN_S = 48 * 3600.0
#: the longest span asked with --hours: ten years
MAX_HOURS = 87_600.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", metavar="MODEL", help="model file, or a library name (sp2)")
    parser.add_argument("--plot", metavar="PNG", default=None, help="write the figure here")
    parser.add_argument("--hours", type=number(0.0, MAX_HOURS, lo_open=True), default=None,
                        help="span (default: 5 τ)")
    parser.add_argument("--force", action="store_true", help="replace an existing --plot file")
    parser.add_argument("--json", action="store_true", help="print the figures as one JSON line")


def _slowest_tau_s(model: object) -> float:
    from models.compensation import CompensationModel
    from models.greybox import GreyBox
    from models.mbotv import Mbotv
    from models.tf import TransferFunction

    if not isinstance(model, CompensationModel):
        return 3600.0
    tau = 60.0
    for t in model.terms:
        dyn = t.dynamics
        mags: list[float] = []
        if isinstance(dyn, TransferFunction):
            mags = [abs(p) for p in dyn.poles]
        elif isinstance(dyn, GreyBox):
            mags = [abs(1.0 + model.period_s * dyn.p[0])]
        elif isinstance(dyn, Mbotv):
            mags = [dyn.k, dyn.gamma]
        for m in mags:
            if 0.0 < m < 1.0:
                tau = max(tau, -model.period_s / math.log(m))
    return tau


def step_responses(model: CompensationModel, n: int
                   ) -> tuple[FloatArray, dict[str, FloatArray], dict[str, str],
                              dict[str, float]]:
    """(time_s, response, unit of the input's step, DC gain) of every term over
    `n` samples: its response from rest to one step of its input (1 K, 1 rpm, ...)
    through its own filters; each filter is left at rest."""
    import numpy as np

    from compd.offline.channel_kind import step_unit

    time_s = np.arange(n, dtype=np.float64) * model.period_s
    responses: dict[str, FloatArray] = {}
    units: dict[str, str] = {}
    gains: dict[str, float] = {}
    for term in model.terms:
        dyn = term.dynamics
        dyn.reset()
        step = dyn.step
        responses[term.name] = term.gain * np.fromiter((step(1.0) for _ in range(n)),
                                                       dtype=np.float64, count=n)
        dyn.reset()
        units[term.name] = step_unit(term.inputs, term.relative)
        gains[term.name] = float(term.gain * dyn.dc_gain)
    return time_s, responses, units, gains


def auto_span_s(model: CompensationModel) -> float:
    """The span shown without --hours: five of the slowest time constant, at most
    `MAX_AUTO_SPAN_S`."""
    return min(5.0 * _slowest_tau_s(model), MAX_AUTO_SPAN_S)


def _g(x: object) -> str:
    return f"{x:.5g}" if isinstance(x, float) else "-"


def run(args: argparse.Namespace) -> int:

    from compd.infiles import load_model
    from compd.outfiles import check_figure, write_atomically
    from models.errors import ModelError

    if args.plot is not None:
        check_figure(args.plot, force=args.force, inputs=[args.model])
    try:
        model = load_model(args.model)
    except ModelError as exc:
        print(f"compd step: {exc}", file=sys.stderr)
        return EX_DATAERR
    settle_s = 5.0 * _slowest_tau_s(model)
    capped = not args.hours and settle_s > MAX_AUTO_SPAN_S
    span_s = args.hours * 3600.0 if args.hours else min(settle_s, MAX_AUTO_SPAN_S)
    samples = span_s / model.period_s + 1.0
    if not samples <= MAX_STEP_SAMPLES:
        print(f"compd step: {span_s / 3600:g} h at the model's period {model.period_s:g} s is "
              f"{samples:.3g} samples; at most {MAX_STEP_SAMPLES:,} (shorten --hours)",
              file=sys.stderr)
        return EX_DATAERR
    time_s, responses, units, gains = step_responses(model, max(2, int(samples)))
    summary = [{"name": k, "input_step": f"1 {units[k]}", "y0_um": float(v[0]),
                "y_end_um": float(v[-1]), "hours": float(time_s[-1] / 3600.0),
                "dc_gain_um": gains[k] if math.isfinite(gains[k]) else None,
                "per": units[k],
                "span_capped": capped}
               for k, v in responses.items()]
    if args.plot:
        from compd.offline.plots import step_figure

        title = f"{model.name}: step response per term (Ts = {model.period_s:g} s)"
        write_atomically(args.plot, lambda tmp: step_figure(tmp, time_s, responses, units,
                                                            title=title, dc_gains=gains),
                         "figure", force=args.force, inputs=[args.model])
    if args.json:
        print(json.dumps({"terms": summary}))
    else:
        if capped:
            print(f"span capped at {MAX_AUTO_SPAN_S / 3600:g} h (five time constants would be "
                  f"{settle_s / 3600:.3g} h; give --hours): the value at the span's end is "
                  "short of the DC gain")
        for s in summary:
            gain, end = s["dc_gain_um"], s["y_end_um"]
            share = (f" ({100.0 * end / gain:.1f} % of it)"
                     if isinstance(gain, float) and isinstance(end, float) and gain != 0.0
                     else "")
            print(f"{s['name']}: step of {s['input_step']}: y(0) = {s['y0_um']:.5g} µm, "
                  f"y({s['hours']:.3g} h, the span's end) = {s['y_end_um']:.5g} µm; "
                  f"DC gain {_g(gain)} µm/{s['per']}{share}")
        if args.plot:
            print(f"figure: {args.plot}")
    return 0
