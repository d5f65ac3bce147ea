"""A `compd plan` program of 2 h run end to end in a real, headless LinuxCNC
(issue 23's third figure): recorded by `compd run`, fitted by `compd fit`.

``compd plan --hours 2 --speeds 3000,6000,9000 --dialect linuxcnc
--time-scale N`` (every dwell divided by N: LinuxCNC dwells in real time, so
the plant and the daemon run at N machine seconds per real second and the
dwells are divided), LinuxCNC runs it with the plant turning at LinuxCNC's
``spindle.0.speed-out``, ``compd run`` records the temperatures, the speed
and the plant's true growth (``dz_um``) with the plan's recorder settings,
``compd fit`` fits the database and ``compd replay`` scores the model on a
2 h spindle-speed spectrum it has never seen. The steps are in
`tests.compd.offline.plan.plan_linuxcnc_run`.

Peer, same run: the same plan played on the same plant without LinuxCNC or
the daemon (the schedule as the plant's own spindle program, recorded
offline at 60 s as benchmarks/bench_plan.py does, the same seed, its dz_um
the true growth as the run's), fitted
and replayed alike: what LinuxCNC, the compressed real-time run, the HAL
signals and the recorder cost the fit, if anything.

Printed: the program's real time against its dwell, the plant's tick
overruns (a late tick slows the plant's time against LinuxCNC's), the steps
the record holds (rpm, machine minutes; the plan: 15 min each), the fit's
figures (fit %, Δpk, forward-validation fit %) and the replay's on the
unseen spectrum, beside the peer's; then all of it as one JSON line.

Run: OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_plan_linuxcnc.py
     [--time-scale N] [--hours H] [--keep DIR]
Needs linuxcnc-uspace (exit 69 with the reason where it is absent); takes
LinuxCNC's one-per-machine lock (/tmp/compd-linuxcnc.lock), waiting for it; exit 69
with the reason where a LinuxCNC it did not start runs (never touched).
"""

from __future__ import annotations

import argparse
import bisect
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from compd.argtypes import count, number  # noqa: E402
from compd.offline.plan.schedule import design  # noqa: E402
from compd.sysexits import EX_UNAVAILABLE  # noqa: E402
from drivers.sim.linuxcnc_machine import (  # noqa: E402
    ForeignLinuxCnc,
    LinuxCncBusy,
    unavailable,
)
from drivers.sim.offline import record_program  # noqa: E402
from drivers.sim.programs import Program  # noqa: E402
from tests.compd.offline.plan.plan_linuxcnc_run import (  # noqa: E402
    PERIOD_S,
    SPEEDS,
    fit_and_replay,
    fit_and_replay_record,
    run_plan,
)


def offline_peer(folder: Path, hours: float, seed: int) -> tuple[dict[str, Any],
                                                                 dict[str, Any]]:
    """The plan's schedule as the plant's own program, recorded offline, fitted
    and replayed as the LinuxCNC run is."""
    exp = design(hours, list(SPEEDS))
    starts = [s.start_ms / 1000 for s in exp.steps]

    def speed(t_s: float) -> float:
        return float(exp.steps[bisect.bisect_right(starts, t_s) - 1].speed_rpm)

    peer = folder / "peer"
    peer.mkdir(exist_ok=True)
    record = peer / "plan.csv"
    # dz_um the true growth, as the LinuxCNC run records it (no probe noise)
    record_program(record, Program("plan", exp.duration_ms / 1000, speed), seed=seed,
                   period_s=PERIOD_S, probe_noise_um=0.0)
    return fit_and_replay_record(record, peer / "model.toml", hours)


def _fit_figures(fit: dict[str, Any]) -> dict[str, Any]:
    selection = fit["terms"][0]["selection"]
    record = fit["records"][0]
    return {"fit_percent": round(fit["fit_percent"], 2), "dpk_um": round(fit["dpk_um"], 3),
            "range_reduction": round(record["range_reduction"], 2),
            "structure": selection["structure"], "orders": selection["orders"],
            "validation_fit_percent": round(selection["validation_fit_percent"], 2),
            "dc_gain_um_per_k": {t["name"]: round(t["dc_gain_um_per_k"], 3)
                                 for t in fit["terms"]}}


def _replay_figures(replay: dict[str, Any]) -> dict[str, float]:
    return {k: round(replay[k], 3) for k in
            ("fit_percent", "mae_um", "rms_um", "dpk_um", "range_reduction")}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--time-scale", type=number(1.0, 10_000.0), default=120.0,
                        help="machine seconds per real second (default 120: 2 h in 60 s)")
    parser.add_argument("--hours", type=number(0.5, 24.0), default=2.0)
    parser.add_argument("--seed", type=count(0, 2**31), default=3)
    parser.add_argument("--keep", type=Path, default=None,
                        help="a folder to keep the files in (default: a temporary one)")
    args = parser.parse_args()
    why = unavailable()
    if why is not None:
        print(f"bench_plan_linuxcnc: {why}", file=sys.stderr)
        return EX_UNAVAILABLE
    with tempfile.TemporaryDirectory(prefix="bench-plan-lcnc-") as tmp:
        try:
            run = run_plan(args.keep or Path(tmp), hours=args.hours,
                           time_scale=args.time_scale, seed=args.seed)
        except (ForeignLinuxCnc, LinuxCncBusy) as exc:
            print(f"bench_plan_linuxcnc: {exc}", file=sys.stderr)
            return EX_UNAVAILABLE
        fit, replay = fit_and_replay(run)
        peer_fit, peer_replay = offline_peer(run.folder, args.hours, args.seed)
    figures = {
        "figure": "plan_linuxcnc", "hours": args.hours, "time_scale": args.time_scale,
        "speeds_rpm": list(SPEEDS), "dwell_real_s": args.hours * 3600.0 / args.time_scale,
        "program_real_s": round(run.program_real_s, 2), "plant_ticks": run.plant_ticks,
        "plant_overruns": run.plant_overruns, "rows": len(run.rows),
        "steps": [[rpm, round(minutes, 1)] for rpm, minutes in run.steps()],
        "fit": _fit_figures(fit),
        "replay_spectrum": _replay_figures(replay),
        "peer_offline": {"fit": _fit_figures(peer_fit),
                         "replay_spectrum": _replay_figures(peer_replay)}}
    print(f"compd plan --hours {args.hours:g} --speeds {','.join(map(str, SPEEDS))} "
          f"--dialect linuxcnc --time-scale {args.time_scale:g}")
    print(f"LinuxCNC ran it in {run.program_real_s:.1f} s (dwell "
          f"{figures['dwell_real_s']:.1f} s); plant ticks {run.plant_ticks}, overruns "
          f"{run.plant_overruns}; compd run recorded {len(run.rows)} rows")
    print("steps recorded (rpm, machine min): "
          + ", ".join(f"{rpm} {m:.0f}" for rpm, m in figures["steps"]))
    print(f"{'':28} {'fit %':>7} {'Δpk µm':>7} {'valid. %':>8} {'replay fit %':>12} "
          f"{'MAE µm':>7} {'RMS µm':>7} {'range x':>7}")
    for name, figs in (("LinuxCNC + compd run", figures),
                       ("peer: offline, same plan", figures["peer_offline"])):
        f, r = figs["fit"], figs["replay_spectrum"]
        print(f"{name:28} {f['fit_percent']:7.2f} {f['dpk_um']:7.3f} "
              f"{f['validation_fit_percent']:8.2f} {r['fit_percent']:12.2f} "
              f"{r['mae_um']:7.3f} {r['rms_um']:7.3f} {r['range_reduction']:7.2f}")
    print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    sys.exit(main())
