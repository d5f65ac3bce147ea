"""Position-dependent compensation of a ball-screw X axis: the error at each
measured position on a held-out day, three ways.

(a) no compensation; (b) a position-independent offset, as compd writes for
Z today: one model fitted to the mean of the positions' displacements; (c)
a value at the reference position plus a slope, each with its own model
(`models.identify.positions`: the ARX least squares with order selection of
`compd fit`'s baseline; with ``--via-fit`` the model files `compd fit
--positions` writes with its whole structure choice, stepped as `compd replay
--init rest` steps them). The value and the offset from every temperature,
the slope from the screw's nut and bearing temperatures.

Peer: (a) and (b) on the same held-out rows. The figure of merit is the share
of the position-dependent part of the error that the slope removes:

    position-dependent part of a residual r = r - mean over positions of r
    share removed = 1 - RMS(dependent part, c) / RMS(dependent part, b)

(goal: >= 80 %). Training: `compd sim --machine ballscrew` for 48 h (seed 1);
held out: 24 h of another duty cycle (seed 2; ``--seed N``: N and N + 1).
Or two records of one's own:

    .venv/bin/python benchmarks/bench_axes.py [--seed N] [--via-fit]
    .venv/bin/python benchmarks/bench_axes.py --train A.csv --heldout B.csv

A record without two or more ``dx_at_<x>mm_um`` columns is refused with one
line on stderr (exit 65).

The issue's other figures, from the same script:

    .venv/bin/python benchmarks/bench_axes.py --real [--blocks …] [ch1 …]
        the real record's five channels fitted as five axes (`bench_axes_real`)
    .venv/bin/python benchmarks/bench_axes.py --cost [--cycles N] [--repeats N]
        X, Y, Z written as value + slope against the Z offset alone, CPU per cycle
        of the model step, the pure cycle and the whole daemon (`bench_axes_cost`)
"""

from __future__ import annotations

import argparse
import contextlib
import io
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from compd.errors import CompdError
from compd.offline.position_record import PositionRecord, read_position_record
from compd.sysexits import EX_DATAERR
from drivers.sim.ballscrew import simulate_ballscrew, write_ballscrew_record
from models.identify.positions import (
    fit_line_model,
    fit_value_slope,
    predict_at,
    predict_line_model,
)

#: the value's and the offset's inputs, and the slope's (the screw's own sensors)
VALUE_INPUTS = ("column", "screw_bearing", "ambient", "nut")
SLOPE_INPUTS = ("nut", "screw_bearing")
GOAL_PCT = 80.0


def _record(path: str | None, hours: float, seed: int, scratch: Path) -> PositionRecord:
    """The record at `path`, or a simulated one written to `scratch` as `compd sim
    --machine ballscrew --record` writes it."""
    if path is None:
        write_ballscrew_record(scratch, simulate_ballscrew(hours, seed=seed))
        path = str(scratch)
    return read_position_record(Path(path))


def residuals(train: PositionRecord, heldout: PositionRecord) -> dict[str, np.ndarray]:
    """The held-out residuals (rows × positions) of each way."""
    if train.positions_mm != heldout.positions_mm:
        raise CompdError(f"the records measure different positions: {train.positions_mm} "
                         f"and {heldout.positions_mm} mm")
    x0 = train.positions_mm[0]
    measured = heldout.displacements()
    fit = fit_value_slope(train.positions_mm, train.displacements(), train.record.columns,
                          value_inputs=VALUE_INPUTS, slope_inputs=SLOPE_INPUTS, x0_mm=x0)
    offset_model = fit_line_model(train.displacements().mean(axis=1), train.record.columns,
                                  VALUE_INPUTS)
    offset = predict_line_model(offset_model, heldout.record.columns, VALUE_INPUTS)
    return {"none": measured, "offset": measured - offset[:, None],
            "value+slope": measured - predict_at(fit, heldout.record.columns,
                                                 heldout.positions_mm)}


def residuals_via_fit(train: PositionRecord, heldout: PositionRecord,
                      workdir: Path) -> dict[str, np.ndarray]:
    """The same three ways through the command line: `compd fit --positions` writes
    the value, slope and offset model files (the offset: the value at the mean of
    the positions, which is the mean of the line there), and they are stepped over
    the held-out record as `compd replay --init rest` steps a model."""
    from compd.cli import main as compd
    from compd.infiles import load_model
    from compd.offline.model_replay import replay_with_init
    from compd.offline.position_record import SLOPE_COLUMN, VALUE_COLUMN, with_line_columns

    x0 = train.positions_mm[0]

    def fitted(column: str, inputs: Sequence[str], ref_mm: float, name: str) -> np.ndarray:
        out = workdir / f"{name}.toml"
        argv = ["fit", train.record.path, "--positions", f"--reference-position-mm={ref_mm}",
                "--column", column, *(a for i in inputs for a in ("--term", i)),
                "--no-fallbacks", "--json", "-o", str(out)]
        said = io.StringIO()
        with contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
            code = compd(argv)
        if code:
            raise CompdError(f"compd {' '.join(argv)} exited {code}: {said.getvalue()}")
        held = with_line_columns(heldout.record, ref_mm)
        return replay_with_init(load_model(out), held, held.column(column), "rest")

    value = fitted(VALUE_COLUMN, VALUE_INPUTS, x0, "value")
    slope = fitted(SLOPE_COLUMN, SLOPE_INPUTS, x0, "slope")
    offset = fitted(VALUE_COLUMN, VALUE_INPUTS, float(np.mean(train.positions_mm)), "offset")
    measured = heldout.displacements()
    dx = (np.asarray(heldout.positions_mm) - x0) / 1000.0
    return {"none": measured, "offset": measured - offset[:, None],
            "value+slope": measured - (value[:, None] + slope[:, None] * dx[None, :])}


def _dependent(r: np.ndarray) -> np.ndarray:
    centred: np.ndarray = r - r.mean(axis=1, keepdims=True)
    return centred


def _rms(v: np.ndarray) -> float:
    return float(np.sqrt(np.mean(v ** 2)))


def report(train: PositionRecord, heldout: PositionRecord,
           res: dict[str, np.ndarray] | None = None) -> float:
    """Print the table (of `residuals` unless given); return the share (%) of the
    position-dependent part removed."""
    res = res if res is not None else residuals(train, heldout)
    positions = heldout.positions_mm
    print(f"held-out {heldout.record.path}: {len(heldout.record)} rows; trained on "
          f"{train.record.path}: {len(train.record)} rows")
    print("error at each position, MAE / RMS (µm)")
    print(f"{'position':>10} " + " ".join(f"{name:>16}" for name in res))
    for j, x in enumerate(positions):
        cells = [f"{np.mean(np.abs(r[:, j])):7.2f} /{_rms(r[:, j]):7.2f}" for r in res.values()]
        print(f"{x:>8g}mm " + " ".join(f"{c:>16}" for c in cells))
    dep = {name: _rms(_dependent(r)) for name, r in res.items()}
    print("position-dependent part, RMS (µm): "
          + ", ".join(f"{name} {v:.2f}" for name, v in dep.items()))
    share = (1.0 - dep["value+slope"] / dep["offset"]) * 100.0 if dep["offset"] else 0.0
    verdict = "meets" if share >= GOAL_PCT else "misses"
    print(f"share of the position-dependent part removed by the slope: {share:.1f} % "
          f"({verdict} the goal of {GOAL_PCT:g} %)")
    return share


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["--real"]:
        import bench_axes_real

        return bench_axes_real.main(argv[1:])
    if argv[:1] == ["--cost"]:
        import bench_axes_cost

        return bench_axes_cost.main(argv[1:])
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--train", metavar="CSV", help="training record (default: simulated)")
    parser.add_argument("--heldout", metavar="CSV", help="held-out record (default: simulated)")
    parser.add_argument("--seed", type=int, default=1,
                        help="simulated: train on this seed, hold out the next (default 1)")
    parser.add_argument("--via-fit", action="store_true",
                        help="fit with compd fit --positions (each model file written, then "
                             "stepped as compd replay --init rest) instead of the library")
    args = parser.parse_args(argv)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            workdir = Path(tmp)
            train = _record(args.train, 48.0, args.seed, workdir / "train.csv")
            heldout = _record(args.heldout, 24.0, args.seed + 1, workdir / "heldout.csv")
            print("models:", "compd fit --positions" if args.via_fit
                  else "models.identify.positions")
            report(train, heldout,
                   residuals_via_fit(train, heldout, workdir) if args.via_fit else None)
    except (CompdError, ValueError) as exc:
        print(f"bench_axes: {exc}", file=sys.stderr)
        return EX_DATAERR
    return 0


if __name__ == "__main__":
    sys.exit(main())
