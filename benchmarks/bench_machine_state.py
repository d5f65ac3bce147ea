"""Issue 34's figures: a warm start and a re-zero, on the simulated machine.

The simulated machine (`drivers.sim.plant.ThermalPlant`, seed per run) and its
bundled model (`sim_machine`, 60 s period) driven through the daemon's own cycle
(`compd.core.cycle.Cycle`, plan and commit at each sample, the controller
accepting every write; the output stage as `compd/examples`: ±200 µm, 0.2 µm/s).
The model's calibration reference is the machine at rest at t = 0 (its sensors
then), as a touch-off on the cold machine records it.

Warm start: the spindle runs at 9,000 rpm from t = 0; a daemon that ran until
2 h stops (its checkpoint saved then), and one starts at 3 h, no fresh
checkpoint. Two cases from 3 h on: the spindle runs on, or stops (the machine
cools). The error at the tool (growth - offset in force) over the first hour
after the start, RMS and largest, for each way to start:

- rest: the reference is the first sample's temperatures and the filters at
  rest (what every start without a fresh checkpoint did): it predicts the
  growth since the start only;
- steady: the steady state of the first sample's inputs against the
  calibration reference;
- advanced: the 2 h checkpoint's state stepped over the hour since it with the
  first sample's inputs held (what `compd run` does with a too-old checkpoint
  of the same model); its output starts from the checkpoint's offset (what the
  controller still holds), the others' from 0 (a first start), so their
  largest error is the output stage's first ramp (12 µm a cycle): the RMS from
  the 10th minute compares the estimates alone;
- none: no compensation (the growth itself).

Re-zero: on the warm machine (spindle on, 3 h), the cycle is re-zeroed
(`Cycle.rezero`, what `compd rezero`, OPC UA Rezero and `[output] rezero`
do): the largest change of the offset between two cycles in the hour around it,
against the slew limit's 0.2 µm/s × 60 s, and the offset the re-zero takes
away (a re-zero that zeroed the offset at once would step the tool by it).

Run: .venv/bin/python benchmarks/bench_machine_state.py [SEEDS…]   (default 0 1 2)
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable
from itertools import pairwise

from compd.core.cycle import WRITTEN, Cycle, CycleParams
from compd.core.validation import ChannelLimits
from compd.infiles import load_model
from drivers.base import Sample
from drivers.sim.plant import ThermalPlant
from models.compensation import CompensationModel

PERIOD_S = 60.0
LIMIT_UM = 200.0
SLEW_UM_S = 0.2
SPEED_RPM = 9000.0
CHANNELS = ("bearing", "motor", "column", "ambient")


def _params() -> CycleParams:
    return CycleParams(period_s=PERIOD_S, hold_s=600.0, limit_um=LIMIT_UM,
                       slew_um_s=SLEW_UM_S, readback=False,
                       channels={n: ChannelLimits(-50.0, 200.0) for n in CHANNELS})


def _model(reference: dict[str, float] | None) -> CompensationModel:
    """The bundled model with `reference` as its calibration reference; None: with
    none at all (its own ``[reference]`` dropped too), so a start takes the first
    sample's temperatures as the reference, the filters at rest."""
    m = load_model("sim_machine")
    m.calibration_reference = {} if reference is None else dict(reference)
    return m


def _cycle_step(cycle: Cycle, t: float, sensors: dict[str, float]) -> float:
    cycle.plan(t, {n: Sample(sensors[n], t) for n in CHANNELS}, wall_s=t)
    return cycle.commit(WRITTEN).stage_um


def _warm(seed: int, speed_after_rpm: float,
          start: Callable[[dict[str, float], dict[str, object]], Cycle | None]
          ) -> tuple[float, float, float]:
    """RMS and largest |error| (µm) over the hour after a start at 3 h, and the RMS
    from its 10th minute (the output stage's first ramp from 0 done)."""
    plant = ThermalPlant(seed)
    first = plant.sensors()
    reference = {n: first[n] for n in CHANNELS}
    early = Cycle(_params(), _model(reference))
    saved: dict[str, object] | None = None
    t = 0.0
    while t < 3 * 3600.0:
        plant.step(PERIOD_S, SPEED_RPM)
        t += PERIOD_S
        if t <= 2 * 3600.0:
            _cycle_step(early, t, plant.sensors())
            if t == 2 * 3600.0:
                saved = early.export_state()
    assert saved is not None
    cycle = start(reference, saved)
    errors = []
    for _ in range(60):
        plant.step(PERIOD_S, speed_after_rpm)
        t += PERIOD_S
        offset = _cycle_step(cycle, t, plant.sensors()) if cycle is not None else 0.0
        errors.append(plant.growth_um() - offset)
    def rms(e: list[float]) -> float:
        return math.sqrt(sum(x * x for x in e) / len(e))

    return rms(errors), max(abs(e) for e in errors), rms(errors[10:])


STARTS: dict[str, Callable[[dict[str, float], dict[str, object]], Cycle | None]] = {
    "none": lambda ref, saved: None,
    "rest": lambda ref, saved: Cycle(_params(), _model(None)),
    "steady": lambda ref, saved: Cycle(_params(), _model(ref)),
    "advanced": lambda ref, saved: Cycle.from_state(_params(), _model(ref), None, saved,
                                                     fresh=False, age_s=3600.0),
}


def _rezero(seed: int) -> tuple[float, float, float]:
    """(largest offset change per cycle, the slew step, the offset taken away), µm."""
    plant = ThermalPlant(seed)
    first = plant.sensors()
    cycle = Cycle(_params(), _model({n: first[n] for n in CHANNELS}))
    t, offsets, taken = 0.0, [], math.nan
    while t < 4 * 3600.0:
        plant.step(PERIOD_S, SPEED_RPM)
        t += PERIOD_S
        offsets.append(_cycle_step(cycle, t, plant.sensors()))
        if t == 3 * 3600.0:
            taken = offsets[-1]
            cycle.rezero("bench", t)
    around = offsets[int(2.5 * 60):]
    step = max(abs(b - a) for a, b in pairwise(around))
    return step, SLEW_UM_S * PERIOD_S, taken


def main(argv: list[str]) -> int:
    seeds = [int(a) for a in argv] or [0, 1, 2]
    print("warm start at 3 h (spindle 9,000 rpm from 0 h; checkpoint saved at 2 h): "
          "error over the first hour,\n  RMS / largest |e| / RMS from the 10th minute, µm "
          "(rest, steady: a first start, the offset ramps from 0 at 12 µm a cycle; "
          "advanced: from the checkpoint's offset)")
    for label, speed in (("spindle runs on", SPEED_RPM), ("spindle stopped", 0.0)):
        for seed in seeds:
            cells = []
            for name, start in STARTS.items():
                rms, peak, settled = _warm(seed, speed, start)
                cells.append(f"{name} {rms:4.1f} / {peak:4.1f} / {settled:4.1f}")
            print(f"  {label:16s} seed {seed}:  " + "   ".join(cells))
    print("re-zero at 3 h on the warm machine: largest offset change between two cycles "
          "(the slew limit's step), and the offset the re-zero takes away")
    for seed in seeds:
        step, limit, taken = _rezero(seed)
        print(f"  seed {seed}: largest step {step:.3f} µm (limit {limit:.1f} µm per "
              f"{PERIOD_S:g} s cycle), offset taken away {taken:.1f} µm, ramped over "
              f"{abs(taken) / (SLEW_UM_S * 60):.1f} min")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
