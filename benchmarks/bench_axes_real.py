"""The five channels of the real record fitted as five axes, each scored with
the calibration yardstick (`bench_real_record`).

Each displacement channel of tests/data/fl_thermal/calibration.csv is taken as
an axis of its own: its own `compd fit` (``--candidates 't*_degC' --candidates
spindle_rpm --max-terms 3``), its own model file, its own held-out figure. The
protocol is the yardstick's, imported, not copied: for each held-out block the
rows of the block are masked from every loss of the fit, the written model runs
from the record's start (from rest) and is scored on the block only, beside the
textbook ARX(2,3) fitted on the same rows (`bench_real_record.run`).

The source does not name the directions of the channels: ch3 and ch4 move
together and are the largest (most likely Z, the spindle's axial growth); ch1,
ch2 and ch5 are the smaller ones (X or Y, not said). The table names each axis
by its channel and says which reading the record's README gives.

Printed: per axis and block the held-out MAE of compd, of the textbook and of no
compensation (µm), and per axis the ratio to the textbook's MAE over every
block (geometric mean and worst; the yardstick's goals: worst ≤ 1, geometric
mean ≤ 0.7).

Run: OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_axes.py --real
[--blocks NAME,NAME…] [ch1 ch3 …]
"""

from __future__ import annotations

import argparse
import math
import tempfile
from collections.abc import Sequence
from pathlib import Path

import bench_real_record as yardstick
import numpy as np

#: what the record's README says of each channel's direction
DIRECTION = {"ch1_um": "X or Y (not named)", "ch2_um": "X or Y (not named)",
             "ch3_um": "Z (axial, most likely)", "ch4_um": "Z (axial, most likely)",
             "ch5_um": "X or Y (not named)"}


def axis_table(cells: Sequence[yardstick.Cell], channels: Sequence[str]) -> None:
    """One row per axis: its held-out MAE of compd, the textbook and no compensation
    (means over the blocks where the textbook found a stable model, so that the three
    are over the same rows), and the ratio of compd's MAE to the textbook's."""
    print("\nfive channels as five axes: held-out MAE (µm, mean over the blocks with a "
          "stable textbook model) and the ratio of compd's MAE to the textbook's")
    print("| axis | direction (README) | blocks | no compensation | textbook ARX(2,3) | "
          "compd | ratio geometric mean | ratio worst | blocks ≤ 1 |")
    print("|---|---|---|---|---|---|---|---|---|")
    for ch in channels:
        mine = [c for c in cells if c.channel == ch and math.isfinite(c.base[0])]
        if not mine:
            continue
        ratios = [c.ratio for c in mine]
        none = float(np.mean([c.none_mae for c in mine]))
        base = float(np.mean([c.base[0] for c in mine]))
        ours = float(np.mean([c.compd[0] for c in mine]))
        print(f"| {ch.removesuffix('_um')} | {DIRECTION.get(ch, '?')} | {len(mine)} | "
              f"{none:.2f} | {base:.2f} | {ours:.2f} | {yardstick.geo(ratios):.2f} | "
              f"{yardstick.worst(ratios):.2f} | {sum(r <= 1.0 for r in ratios)} of "
              f"{len(ratios)} |")


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("channels", nargs="*", help="ch1 … ch5 (default: every one)")
    parser.add_argument("--blocks", default="",
                        help="comma-separated block names (default: every one: "
                             + ", ".join(b[0] for b in yardstick.BLOCKS) + ")")
    args = parser.parse_args(argv)
    channels = [c if c.endswith("_um") else f"{c}_um" for c in args.channels] \
        or list(yardstick.CHANNELS)
    unknown = [c for c in channels if c not in yardstick.CHANNELS]
    if unknown:
        parser.error(f"no channel {unknown[0]!r}: the record has "
                     + ", ".join(yardstick.CHANNELS))
    wanted = [b.strip() for b in args.blocks.split(",") if b.strip()]
    blocks = [b for b in yardstick.BLOCKS if not wanted or b[0] in wanted]
    if wanted and len(blocks) != len(wanted):
        parser.error(f"--blocks {args.blocks!r}: known blocks are "
                     + ", ".join(b[0] for b in yardstick.BLOCKS))
    d = yardstick.read(yardstick.RECORD)
    print(f"record {yardstick.RECORD.name}: {d['time_s'].size} rows; each channel its own "
          f"axis and model; blocks: " + ", ".join(b[0] for b in blocks))
    with tempfile.TemporaryDirectory() as tmp:
        cells = yardstick.run(yardstick.RECORD, d, blocks, channels, Path(tmp))
    yardstick.print_table(cells, [b[0] for b in blocks], channels)
    axis_table(cells, channels)
    return 0
