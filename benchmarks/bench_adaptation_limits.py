"""Why adaptation does not reach issue 13's 1.5x on the shop machine: the limits.

Per seed, the same records and calibration as benchmarks/bench_adaptation.py
(48 h, day 1 to fit, day 2 scored; with and without the change from hour 24):

1. hindsight: the best a bias and per-term gain corrections could do if they
   were known from every sample of day 2 (least squares of the residue on
   [1, term contributions] over day 2: not causal, an upper bound of what the
   estimator's structure can express), as a ratio to the plain range reduction;
2. the probe interval: the estimator with gains (`--gains`, defaults
   otherwise) with a probe every 600, 1800, 3600 and 7200 s (0.5 µm noise).

Run: OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_adaptation_limits.py [SEEDS…]
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np
from bench_adaptation import _day1, _run

INTERVALS = (600, 1800, 3600, 7200)


def hindsight(model_path: Path, record_path: Path) -> float:
    """Range reduction of the best bias + gains on day 2, over the plain one."""
    from compd.infiles import load_model
    from compd.offline.model_replay import replay_terms, replay_with_init
    from compd.offline.records import read_record

    model = load_model(str(model_path))
    record = read_record(record_path)
    measured = record.columns["dz_um"]
    simulated = replay_with_init(model, record, measured, "estimate")
    terms = replay_terms(model, record)
    first = int(np.searchsorted(record.time_s, 86400 - 1e-9))
    r = (measured - simulated)[first:]
    x = np.column_stack([np.ones(r.size), terms[first:]])
    coef, *_ = np.linalg.lstsq(x, r, rcond=None)
    return float(np.ptp(r) / np.ptp(r - x @ coef))


def seed_limits(d: Path, seed: int) -> None:
    plain, changed = d / f"plain{seed}.csv", d / f"changed{seed}.csv"
    common = ["--machine", "shop", "--hours", "48", "--period-s", "60", "--seed", str(seed)]
    _run(["sim", "--record", str(plain), *common])
    _run(["sim", "--record", str(changed), *common, "--change", "ambient+3K,heat+30%",
          "--change-at-h", "24"])
    day1, model = d / f"day1-{seed}.csv", d / f"shop{seed}.toml"
    _day1(plain, day1)
    _run(["fit", str(day1), "--column", "dz_um", "--candidates", "t*_degC", "--candidates",
          "spindle_rpm", "--max-terms", "3", "-o", str(model), "--json"])
    for name, record in (("without change", plain), ("with change", changed)):
        ratios = []
        for every in INTERVALS:
            r = _run(["replay", str(model), str(record), "--column", "dz_um", "--score-from",
                      "86400", "--probe-every-min", f"{every / 60:g}", "--probe-noise-um", "0.5",
                      "--gains", "--json"])
            ratios.append(r["adapted"]["range_reduction"] / r["range_reduction"])
        sweep = ", ".join(f"{e} s {x:.2f}" for e, x in zip(INTERVALS, ratios, strict=True))
        print(f"  seed {seed}, day 2 {name}: hindsight bias+gains "
              f"{hindsight(model, record):.2f}x plain; --gains, a probe every {sweep}",
              flush=True)


def main() -> None:
    seeds = [int(a) for a in sys.argv[1:]] or list(range(1, 9))
    with tempfile.TemporaryDirectory() as tmp:
        for s in seeds:
            seed_limits(Path(tmp), s)
    print("(ratios to the plain model's range reduction on day 2)")


if __name__ == "__main__":
    main()
