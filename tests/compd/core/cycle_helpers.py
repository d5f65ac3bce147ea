"""Shared fakes for the pure-cycle tests: sample sets (the fake clock is
`compd.testing.FakeClock`)."""

from __future__ import annotations

from compd.core.cycle import Cycle, CycleParams
from compd.core.validation import ChannelLimits
from compd.infiles import load_model
from compd.testing import FakeClock
from drivers.base import Quality, Sample
from models.compensation import CompensationModel

PERIOD_S = 1.0
HOLD_S = 60.0
LIMIT_UM = 100.0
SLEW_UM_S = 1.0


def params(**overrides: object) -> CycleParams:
    base: dict[str, object] = dict(
        period_s=PERIOD_S, hold_s=HOLD_S, limit_um=LIMIT_UM, slew_um_s=SLEW_UM_S,
        channels={
            "bearing": ChannelLimits(-20.0, 150.0, max_rate_per_s=0.5, stale_after_s=30.0,
                                     stuck_after_s=3600.0),
            "ambient": ChannelLimits(-10.0, 60.0, max_rate_per_s=0.1, stale_after_s=30.0),
            "spindle_rpm": ChannelLimits(0.0, 30000.0),
        },
        readback=False)
    base.update(overrides)
    return CycleParams(**base)  # type: ignore[arg-type]


def sp2() -> CompensationModel:
    return load_model("sp2")


def samples(t_s: float, bearing: float, ambient: float = 20.0, speed: float = 1000.0,
            quality: Quality = Quality.GOOD, ts_s: float | None = None) -> dict[str, Sample]:
    ts = t_s if ts_s is None else ts_s
    return {"bearing": Sample(bearing, ts, quality), "ambient": Sample(ambient, ts),
            "spindle_rpm": Sample(speed, ts)}


def run_warm(cycle: Cycle, clock: FakeClock, n: int, bearing: float = 25.0,
             ambient: float = 20.0) -> None:
    for _ in range(n):
        t = clock.tick()
        cycle.plan(t, samples(t, bearing, ambient))
        cycle.commit()
