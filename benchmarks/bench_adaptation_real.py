"""Issue 20's yardstick: adaptation on a REAL machine's record, against the crude baseline.

The record is the vendored FL_THERMAL calibration part (tests/data/fl_thermal/,
27.8 h, 15 s). Per channel (ch3_um, ch4_um: the Z growth) it runs a forward
split through the command line as a user would:

1. calibrate on the first 20.1 h only (`compd fit FIRST.csv --column CH --term
   t4_degC --term t6_degC --adaptation --adaptation-lag-s EVERY`: the same code
   `compd fit` runs, the drift suggestion measured at the probe spacing);
2. replay the whole record from rest (`compd replay MODEL calibration.csv
   --init rest --score-from 72360`), scored on the 7.7 h after the calibration
   rows, with a probe every 1, 2, 4 and 8 h taken from the measured channel,
   without and with 0.5 µm of seeded noise (`--probe-every-min --probe-noise-um`).

Printed per row: the residue RMS (µm, scored rows) of the plain model, the
estimator with the library defaults (`--adaptation-defaults`: the model
file's learnt [adaptation] table ignored), the estimator with the settings
the model file carries (learnt from the calibration residual by `compd fit
--adaptation`), the same without its self-score (`--score-window 0`: it never
stands down), and the crude correction (each probe's residual held until the next), all
in the same run. The issue's targets: adapted never worse than plain, and at
1 h and 2 h at least as good as crude. "ok" marks a row that meets them.

Run: OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_adaptation_real.py
     [--channel ch3_um] [--seed N]
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import io
import json
import tempfile
from pathlib import Path
from typing import Any

from compd.cli import main as cli

RECORD = Path(__file__).resolve().parent.parent / "tests" / "data" / "fl_thermal" \
    / "calibration.csv"
SPLIT_S = 20.1 * 3600.0
EVERY_H = (1, 2, 4, 8)
NOISE_UM = (0.0, 0.5)
TERMS = ["--term", "t4_degC", "--term", "t6_degC"]
#: the crude baseline may win by rounding only (µm)
SLACK_UM = 1e-6


def _run(argv: list[str]) -> dict[str, Any]:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        code = cli(argv)
    if code != 0:
        raise SystemExit(f"compd {' '.join(argv)} exited {code}")
    text = out.getvalue().strip().splitlines()
    return json.loads(text[-1]) if text and text[-1].startswith("{") else {}


def first_part(d: Path, split_s: float = SPLIT_S, name: str = "first.csv") -> Path:
    """The rows up to `split_s` (20.1 h), as their own CSV (the calibration part of the
    split)."""
    out = d / name
    with RECORD.open(newline="") as src, out.open("w", newline="") as dst:
        rows = csv.reader(src)
        w = csv.writer(dst)
        w.writerow(next(rows))
        w.writerows(r for r in rows if float(r[0]) <= split_s)
    return out


def channel_rows(d: Path, first: Path, channel: str, seed: int) -> list[dict[str, Any]]:
    out = []
    for every_h in EVERY_H:
        model = d / f"{channel}-{every_h}h.toml"
        fit = _run(["fit", str(first), "--column", channel, *TERMS, "--adaptation",
                    "--adaptation-lag-s", str(every_h * 3600), "-o", str(model), "--json"])
        for noise in NOISE_UM:
            argv = ["replay", str(model), str(RECORD), "--column", channel, "--init", "rest",
                    "--score-from", f"{SPLIT_S:g}", "--probe-every-min", str(every_h * 60),
                    "--probe-noise-um", str(noise), "--probe-seed", str(seed), "--json"]
            learnt = _run(argv)
            default = _run([*argv, "--adaptation-defaults"])
            unscored = _run([*argv, "--score-window", "0"])
            a = learnt["adapted"]
            out.append({"channel": channel, "every_h": every_h, "noise_um": noise,
                        "plain": a["plain_residue_rms_um"],
                        "default": default["adapted"]["residue_rms_um"],
                        "learnt": a["residue_rms_um"], "crude": learnt["crude"]["residue_rms_um"],
                        "unscored": unscored["adapted"]["residue_rms_um"],
                        "stand_downs": a["stand_downs"],
                        "suggested": fit.get("adaptation", {}),
                        "used": learnt["adaptation"]})
    return out


def verdict(r: dict[str, Any]) -> str:
    never_worse = r["learnt"] <= r["plain"] + SLACK_UM
    floor = r["every_h"] > 2 or r["learnt"] <= r["crude"] + SLACK_UM
    return "ok" if never_worse and floor else "MISSED"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--channel", action="append", default=None)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    channels = args.channel or ["ch3_um", "ch4_um"]
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        first = first_part(d)
        rows = [r for ch in channels for r in channel_rows(d, first, ch, args.seed)]
    print("residue RMS, µm, on the 7.7 h after the calibration rows (forward split at 20.1 h)")
    print(f"{'channel':8s} {'probe':>6s} {'noise':>6s} {'plain':>7s} {'default':>8s} "
          f"{'learnt':>7s} {'unscored':>8s} {'crude':>7s}  learnt settings used")
    for r in rows:
        u = r["used"]
        print(f"{r['channel']:8s} {r['every_h']:>4d} h {r['noise_um']:>4.1f}µm {r['plain']:7.3f} "
              f"{r['default']:8.3f} {r['learnt']:7.3f} {r['unscored']:8.3f} {r['crude']:7.3f}  "
              f"rw {u['bias_rw_um_per_sqrt_h']:.3g} µm/√h, σ {u['probe_noise_um']:.3g} µm, "
              f"apply {u['apply_sigma']:g}, step {u['max_step_um']:.3g} µm, stood down "
              f"{r['stand_downs']}  {verdict(r)}")
    missed = sum(verdict(r) != "ok" for r in rows)
    print(f"targets (learnt <= plain; <= crude at 1 h and 2 h): met on {len(rows) - missed} "
          f"of {len(rows)}")


if __name__ == "__main__":
    main()
