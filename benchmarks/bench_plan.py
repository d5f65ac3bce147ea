"""Does the experiment `compd plan` designs calibrate a model that generalises?

On the simulated machine (its plant, not G-code: the schedule of `compd plan
--hours 24 --speeds 3000,6000,9000` played as a spindle program), per seed:
record the plan's 24 h at 60 s, fit it with the ETVE run (bearing, motor,
column, ambient, orders 3-3, as the README's recipe), and replay the model on
a spindle-speed spectrum it has never seen (12 h, seeds 7…). Peers in the same
run, fitted and scored the same way: the README's recipe (ISO 230-3 heat-up
and cool-down at 9,000 rpm, 4 h + 4 h) and that heat-up and cool-down
stretched to the plan's 24 h (12 h + 12 h), so that the length of the record
is not what differs.

Run: OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_plan.py [SEEDS…]
"""

from __future__ import annotations

import bisect
import contextlib
import io
import json
import statistics
import sys
import tempfile
from pathlib import Path

from compd.cli import main as cli
from compd.offline.plan.schedule import design
from drivers.sim.offline import record_program
from drivers.sim.programs import Program

SPEEDS = [3000, 6000, 9000]
TERMS = ["--term", "bearing", "--term", "motor", "--term", "column", "--term", "ambient"]


def _run(argv: list[str]) -> dict[str, float]:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        code = cli(argv)
    if code != 0:
        raise SystemExit(f"compd {' '.join(argv)} exited {code}")
    lines = out.getvalue().strip().splitlines()
    return json.loads(lines[-1]) if lines and lines[-1].startswith("{") else {}


def plan_record(path: Path, hours: float, seed: int) -> None:
    exp = design(hours, SPEEDS)
    starts = [s.start_ms / 1000 for s in exp.steps]

    def speed(t_s: float) -> float:
        return float(exp.steps[bisect.bisect_right(starts, t_s) - 1].speed_rpm)

    record_program(path, Program("plan", exp.duration_ms / 1000, speed), seed=seed,
                   period_s=60.0, probe_noise_um=0.5)


def main(seeds: list[int]) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        etve = d / "etve.csv"
        _run(["sim", "--record", str(etve), "--program", "etve", "--period-s", "60",
              "--seed", "1"])
        records = {"plan 24 h": d / "plan.csv", "constant 8 h": d / "c8.csv",
                   "constant 24 h": d / "c24.csv"}
        plan_record(records["plan 24 h"], 24.0, seed=3)
        _run(["sim", "--record", str(records["constant 8 h"]), "--program", "constant",
              "--period-s", "60", "--seed", "2"])
        _run(["sim", "--record", str(records["constant 24 h"]), "--program", "constant",
              "--hours", "24", "--period-s", "60", "--seed", "2"])
        models = {}
        for name, record in records.items():
            models[name] = d / f"{record.stem}.toml"
            _run(["fit", str(record), str(etve), "--column", "dz_um", *TERMS, "--orders",
                  "3-3", "-o", str(models[name])])
        figures: dict[str, list[dict[str, float]]] = {name: [] for name in records}
        for seed in seeds:
            spectrum = d / f"spectrum{seed}.csv"
            _run(["sim", "--record", str(spectrum), "--program", "spectrum", "--period-s",
                  "60", "--seed", str(seed)])
            for name, model in models.items():
                figures[name].append(_run(["replay", str(model), str(spectrum), "--column",
                                           "dz_um", "--json"]))
    print(f"calibrated with the ETVE run; scored on the spectrum, seeds {seeds}")
    print(f"{'calibration run':16} {'fit %':>7} {'MAE um':>7} {'RMS um':>7} {'range x':>8}"
          f" {'RMS / constant 8 h':>19}")
    base = statistics.mean(f["rms_um"] for f in figures["constant 8 h"])
    for name, figs in figures.items():
        fit = statistics.mean(f["fit_percent"] for f in figs)
        mae = statistics.mean(f["mae_um"] for f in figs)
        rms = statistics.mean(f["rms_um"] for f in figs)
        rr = statistics.mean(f["range_reduction"] for f in figs)
        print(f"{name:16} {fit:7.2f} {mae:7.3f} {rms:7.3f} {rr:8.2f} {rms / base:19.3f}")


if __name__ == "__main__":
    main([int(s) for s in sys.argv[1:]] or [7, 8, 9, 10, 11])
