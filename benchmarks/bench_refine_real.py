"""Issue 20 item 1 on a REAL machine's record: settings refined from production probes.

The record is the vendored FL_THERMAL calibration part (tests/data/fl_thermal/).
Per channel (ch3_um, ch4_um) and probe spacing, as a user would:

1. calibrate on the first 14 h only (`compd fit FIRST.csv --column CH --term t4_degC
   --term t6_degC --adaptation --adaptation-lag-s EVERY`): settings learnt from the
   calibration residual;
2. "production" from 14 h to 20.1 h: a probe every EVERY from the measured channel,
   logged as the daemon's recorder would (time_s, measured_um, model_um: the plain
   model replayed from rest), and `compd refine MODEL probes.csv -o REFINED`;
3. replay the whole record from rest (`compd replay … --init rest --score-from 72360
   --probe-every-min EVERY`), scored on the 7.7 h after 20.1 h, which neither step saw,
   with the calibration's settings and with the refined ones, without and with 0.5 µm
   of probe noise; plain and crude in the same run.

The model calibrated on 14 h has not seen the 5000 rpm step: its error grows far
faster than its calibration residual said, which is what production probes show.

Run: OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_refine_real.py
"""

from __future__ import annotations

import csv
import tempfile
from pathlib import Path

from bench_adaptation_real import RECORD, SPLIT_S, TERMS, _run, first_part

from compd.infiles import load_model
from compd.offline.model_replay import replay_with_init
from compd.offline.records import read_record

CAL_S = 14.0 * 3600.0
EVERY_H = (1, 2)


def _probe_log(d: Path, model: Path, channel: str, every_s: float) -> Path:
    rec = read_record(RECORD)
    measured = rec.column(channel)
    plain = replay_with_init(load_model(model), rec, measured, "rest")
    stride = round(every_s / rec.period_s)
    out = d / f"probes-{channel}.csv"
    with out.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["time_s", "measured_um", "model_um"])
        for k in range(0, len(rec), stride):
            if CAL_S < rec.time_s[k] <= SPLIT_S:
                w.writerow([f"{rec.time_s[k]:g}", measured[k], plain[k]])
    return out


def main() -> None:
    print("residue RMS, µm, on the 7.7 h after 20.1 h; calibrated on 0-14 h, probes "
          "logged 14-20.1 h")
    print(f"{'channel':8s} {'probe':>6s} {'noise':>6s} {'plain':>7s} {'calib.':>7s} "
          f"{'refined':>8s} {'crude':>7s}  rw calib. → refined (µm/√h)")
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        first = first_part(d, CAL_S, "cal.csv")
        for channel in ("ch3_um", "ch4_um"):
            for every_h in EVERY_H:
                every_s = every_h * 3600.0
                model, refined = d / "m.toml", d / "r.toml"
                _run(["fit", str(first), "--column", channel, *TERMS, "--adaptation",
                      "--adaptation-lag-s", f"{every_s:g}", "-o", str(model), "--force"])
                log = _probe_log(d, model, channel, every_s)
                try:
                    fig = _run(["refine", str(model), str(log), "-o", str(refined),
                                "--force", "--json"])
                except SystemExit as exc:
                    print(f"{channel:8s} {every_h:>4d} h  {exc}")
                    continue
                for noise in ("0", "0.5"):
                    argv = ["--column", channel, "--init", "rest", "--score-from",
                            f"{SPLIT_S:g}", "--probe-every-min", f"{every_s / 60:g}",
                            "--probe-noise-um", noise, "--json"]
                    a = _run(["replay", str(model), str(RECORD), *argv])
                    b = _run(["replay", str(refined), str(RECORD), *argv])
                    print(f"{channel:8s} {every_h:>4d} h {float(noise):>4.1f}µm "
                          f"{a['adapted']['plain_residue_rms_um']:7.3f} "
                          f"{a['adapted']['residue_rms_um']:7.3f} "
                          f"{b['adapted']['residue_rms_um']:8.3f} "
                          f"{a['crude']['residue_rms_um']:7.3f}  "
                          f"{fig['before']['bias_rw_um_per_sqrt_h']:.3g} → "
                          f"{fig['after']['bias_rw_um_per_sqrt_h']:.3g} "
                          f"({fig['probes']} probes)")


if __name__ == "__main__":
    main()
