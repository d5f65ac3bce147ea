"""Position-dependent compensation of a ball-screw X axis: the error at each
measured position on a held-out day, three ways.

(a) no compensation; (b) a position-independent offset, as compd writes for
Z today: one model fitted to the mean of the positions' displacements; (c)
a value at the reference position plus a slope, each with its own model
(`models.identify.positions`). All models are the ARX least squares with
order selection of `compd fit`'s baseline; the value and the offset from
every temperature, the slope from the screw's nut and bearing temperatures.

Peer: (a) and (b) on the same held-out rows. The figure of merit is the share
of the position-dependent part of the error that the slope removes:

    position-dependent part of a residual r = r - mean over positions of r
    share removed = 1 - RMS(dependent part, c) / RMS(dependent part, b)

(goal: >= 80 %). Training: `compd sim --machine ballscrew` for 48 h (seed 1);
held out: 24 h of another duty cycle (seed 2; ``--seed N``: N and N + 1).
Or two records of one's own:

    .venv/bin/python benchmarks/bench_axes.py [--seed N]
    .venv/bin/python benchmarks/bench_axes.py --train A.csv --heldout B.csv

A record without two or more ``dx_at_<x>mm_um`` columns is refused with one
line on stderr (exit 65).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from compd.errors import CompdError
from compd.offline.position_record import PositionRecord, position_record, read_position_record
from compd.offline.records import Record
from compd.sysexits import EX_DATAERR
from drivers.sim.ballscrew import simulate_ballscrew
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


def simulated(hours: float, seed: int) -> PositionRecord:
    """A ball-screw record in memory, as `compd sim --machine ballscrew` writes it."""
    cols = simulate_ballscrew(hours, seed=seed)
    t = cols.pop("time_s")
    for truth in ("value_um", "slope_um_m"):
        cols.pop(truth)
    record = Record(path=f"<ballscrew seed {seed}>", sha256="", time_s=t,
                    period_s=float(t[1] - t[0]), columns=cols)
    return position_record(record)


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


def _dependent(r: np.ndarray) -> np.ndarray:
    return r - r.mean(axis=1, keepdims=True)


def _rms(v: np.ndarray) -> float:
    return float(np.sqrt(np.mean(v ** 2)))


def report(train: PositionRecord, heldout: PositionRecord) -> float:
    """Print the table; return the share (%) of the position-dependent part removed."""
    res = residuals(train, heldout)
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
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--train", metavar="CSV", help="training record (default: simulated)")
    parser.add_argument("--heldout", metavar="CSV", help="held-out record (default: simulated)")
    parser.add_argument("--seed", type=int, default=1,
                        help="simulated: train on this seed, hold out the next (default 1)")
    args = parser.parse_args(argv)
    try:
        train = (read_position_record(Path(args.train)) if args.train
                 else simulated(48.0, seed=args.seed))
        heldout = (read_position_record(Path(args.heldout)) if args.heldout
                   else simulated(24.0, seed=args.seed + 1))
        report(train, heldout)
    except (CompdError, ValueError) as exc:
        print(f"bench_axes: {exc}", file=sys.stderr)
        return EX_DATAERR
    return 0


if __name__ == "__main__":
    sys.exit(main())
