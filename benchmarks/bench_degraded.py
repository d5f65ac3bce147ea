"""Degraded mode on the shop simulator: each sensor of the model failed in
turn, the error at the tool with the fallback model against hold-and-ramp.

The shop machine (`drivers.sim.shop`, 16 sensors, starts warm, room drift) is
recorded for a calibration day and, with another seed, a verification day
(`compd sim --record … --machine shop --hours 24 --period-s 60`); `compd fit
--candidates 't*_degC' --candidates spindle_rpm` picks the inputs and writes a
fallback per input. The verification day runs through the daemon's own cycle
(`compd.core.cycle.Cycle`, plan and commit each sample, every write accepted;
±200 µm, 0.2 µm/s), once healthy and, for each input of the model, with that
input reading NaN from hour 4 to the end: once with the model's fallbacks
(degraded) and once without them (today's hold for hold_s = 300 s, then the
ramp to 0). Printed: the RMS and largest error (measured growth - offset in
force) over the failure, and without compensation, in µm.

Run: .venv/bin/python benchmarks/bench_degraded.py [SEED]   (default 1)
"""

from __future__ import annotations

import math
import sys
import tempfile
from pathlib import Path

import numpy as np

from compd.cli import main
from compd.core.cycle import WRITTEN, Cycle, CycleParams
from compd.core.validation import ChannelLimits
from compd.infiles import load_model
from compd.offline.records import read_record
from drivers.base import Sample
from models.compensation import CompensationModel

FAIL_FROM_H = 4.0


def _params(model: CompensationModel, period_s: float) -> CycleParams:
    channels = {ch: (ChannelLimits(0.0, 30000.0) if ch.endswith("rpm")
                     else ChannelLimits(-50.0, 200.0)) for ch in sorted(model.channels)}
    return CycleParams(period_s=period_s, hold_s=300.0, limit_um=200.0, slew_um_s=0.2,
                       channels=channels, readback=False)


def _run(model: CompensationModel, rec: object, lost: str | None) -> np.ndarray:
    """The offset in force at each row; `lost` reads NaN from FAIL_FROM_H on."""
    r = rec  # a compd.offline.records.Record
    t = r.time_s  # type: ignore[attr-defined]
    cols = {ch: r.column(ch) for ch in model.channels}  # type: ignore[attr-defined]
    cycle = Cycle(_params(model, model.period_s), model)
    out = np.zeros(len(t))
    for k, now in enumerate(t):
        samples = {ch: Sample(math.nan if ch == lost and now >= FAIL_FROM_H * 3600.0
                              else float(v[k]), float(now)) for ch, v in cols.items()}
        plan = cycle.plan(float(now), samples)
        cycle.commit(WRITTEN)
        out[k] = plan.stage_um
    return out


def main_(seed: int) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        for name, s in (("cal", seed), ("ver", seed + 100)):
            assert main(["sim", "--record", str(d / f"{name}.csv"), "--machine", "shop",
                         "--hours", "24", "--period-s", "60", "--seed", str(s)]) == 0
        assert main(["fit", str(d / "cal.csv"), "--column", "dz_um", "--candidates",
                     "t*_degC", "--candidates", "spindle_rpm", "-o", str(d / "m.toml")]) == 0
        ver = read_record(str(d / "ver.csv"))
        dz = ver.column("dz_um")
        window = ver.time_s >= FAIL_FROM_H * 3600.0

        def rms(e: np.ndarray) -> str:
            e = e[window]
            return f"RMS {math.sqrt(float(np.mean(e * e))):6.2f}, max {np.max(np.abs(e)):6.2f}"

        model = load_model(d / "m.toml")
        print(f"\nseed {seed}: model inputs {sorted(model.channels)}; fallbacks for "
              f"{sorted(model.fallbacks)}; error at the tool from {FAIL_FROM_H:g} h (µm)")
        print(f"  no compensation           {rms(dz)}")
        print(f"  healthy (no failure)      {rms(dz - _run(load_model(d / 'm.toml'), ver, None))}")
        for lost in sorted(model.channels):
            with_fb = dz - _run(load_model(d / "m.toml"), ver, lost)
            bare = load_model(d / "m.toml")
            bare.fallbacks = {}
            hold = dz - _run(bare, ver, lost)
            print(f"  {lost:>12} lost: fallback {rms(with_fb)} | hold-and-ramp {rms(hold)}")


if __name__ == "__main__":
    main_(int(sys.argv[1]) if len(sys.argv) > 1 else 1)
