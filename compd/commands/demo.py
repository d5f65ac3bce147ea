"""`compd demo`: a simulated machine on loopback and the daemon against it."""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
from typing import TYPE_CHECKING

from compd.argtypes import number, seed
from drivers.protocols import NAMES

if TYPE_CHECKING:
    from models.compensation import CompensationModel

#: the real time between two of the daemon's cycles must be at least this (a faster demo
#: only counts overruns: --hours 1000 in --seconds 0.5 asked for one every 8 µs)
MIN_REAL_PERIOD_S = 0.01

HELP = ("serve a simulated machine on 127.0.0.1, run the daemon against it at a speed-up, "
        "and print the Z error at the tool without and with compensation")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--protocol", choices=NAMES,
                        default="opcua", help="simulated controller (default: opcua)")
    parser.add_argument("--hours", type=number(0.0, 1000.0, lo_open=True), default=8.0,
                        help="machine hours of the spindle-speed spectrum (default 8)")
    parser.add_argument("--seconds", type=number(0.0, 86400.0, lo_open=True), default=60.0,
                        help="real seconds the run should take (sets the speed-up; default 60)")
    parser.add_argument("--model", default="sim_machine",
                        help="model file or bundled name (default: sim_machine, calibrated "
                             "on the simulated machine)")
    parser.add_argument("--program", choices=["spectrum", "constant", "etve"],
                        default="spectrum",
                        help="spindle-speed program the machine runs (default spectrum)")
    parser.add_argument("--seed", type=seed, default=7,
                        help="random seed of the program and the sensor noise (default 7)")
    parser.add_argument("--plot", metavar="PNG", help="draw growth, offset and error")
    parser.add_argument("--force", action="store_true", help="replace an existing --plot file")
    parser.add_argument("--json", action="store_true",
                        help="print the figures as one JSON object, the only thing on "
                             "stdout (the human lines go to stderr)")


def _check_model(path: str) -> CompensationModel:
    """The --model read and judged as `compd check` does before the demo
    starts anything: not a file or not TOML is an InputError (66, 65), not
    a model or a physically absurd one a ConfigError (78)."""
    from compd.errors import ConfigError
    from compd.infiles import load_model
    from models.errors import ModelError
    from models.sanity import check_model

    try:
        model = load_model(path)
        check_model(model)
    except ModelError as exc:
        raise ConfigError("", f"--model {path}: {exc}") from None
    return model


def run(args: argparse.Namespace) -> int:
    import logging

    from compd.outfiles import check_figure, write_atomically

    if args.plot is not None:  # before anything else: the figure is the point of the run
        check_figure(args.plot, force=args.force, inputs=[args.model])
    period_s = _check_model(args.model).period_s
    real_period_s = period_s * args.seconds / (args.hours * 3600.0)
    if not real_period_s >= MIN_REAL_PERIOD_S:  # the daemon's cycle cannot keep up
        from compd.infiles import InputError
        from compd.sysexits import EX_USAGE

        fewest = MIN_REAL_PERIOD_S * args.hours * 3600.0 / period_s
        raise InputError(f"--seconds {args.seconds:g} for --hours {args.hours:g}: the "
                         f"model's {period_s:g} s period would pass every "
                         f"{real_period_s * 1e3:.3g} ms of real time, at least "
                         f"{MIN_REAL_PERIOD_S * 1e3:g} ms is needed; give --seconds "
                         f"{fewest:.3g} or more", EX_USAGE)

    from compd.offline.demo import run_demo

    # the simulated controllers' libraries log every dropped client at ERROR level;
    # the demo reports through its figures (the daemon's own log is in its work dir)
    for name in ("pymodbus", "asyncua", "snap7"):
        logging.getLogger(name).setLevel(logging.CRITICAL)

    # with --json stdout holds the JSON object only: the human lines go to stderr
    human = sys.stderr if args.json else sys.stdout
    print(f"compd demo: {args.hours:g} h of the {args.program} program on a simulated "
          f"{args.protocol} controller, about {args.seconds:g} s", file=human, flush=True)
    from compd.progress import terminal_progress

    bar = terminal_progress("machine time", quiet=args.json, total=args.hours, unit="h")
    try:
        result = asyncio.run(run_demo(args.protocol, hours=args.hours, wall_s=args.seconds,
                                      model=args.model, seed=args.seed, program=args.program,
                                      progress=bar.update if bar.active else None))
    finally:
        bar.done()
    unc, comp = result.uncompensated_range_um, result.compensated_range_um
    print(f"Z error at the tool without compensation: range {unc:7.2f} µm", file=human)
    print(f"Z error at the tool with compensation:    range {comp:7.2f} µm", file=human)
    print(f"range reduction {result.range_reduction:.1f}x, fit {result.fit_percent:.1f} %",
          file=human)
    if args.plot:
        import numpy as np

        from compd.offline.plots import replay_figure

        h = result.history
        inputs: dict[str, np.ndarray] = {
            k: h[k] for k in ("bearing", "motor", "column", "ambient", "spindle_rpm") if k in h}
        write_atomically(args.plot, lambda tmp: replay_figure(
                      tmp, h["time_s"], inputs, h["growth_um"], h["offset_um"],
                      title=(f"compd demo ({args.protocol}): Z growth at the tool, offset "
                             f"written, error left; range {result.uncompensated_range_um:.1f}"
                             f" → {result.compensated_range_um:.1f} µm "
                             f"({result.range_reduction:.1f}x)"),
                      labels=("thermal growth at the tool (uncompensated error)",
                              "offset written by compd", "error left at the tool")),
                         "figure", force=args.force, inputs=[args.model])
        print(f"figure written to {args.plot}", file=human)
    if args.json:
        print(json.dumps(result.summary()))
    return 0
