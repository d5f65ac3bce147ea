"""Issue 20 item 3, through the wire: a model worse than none is caught by the probes.

The simulated Modbus controller, the in-process daemon on the fake clock (one
machine second a cycle, exactly), a bearing that warms the machine, and a model
DELIBERATELY miscalibrated: sp2 with every gain ×2 and its sign flipped, so the
compensation doubles the error the wrong way. A measuring cycle every PROBE_EVERY
cycles leaves what a touch probe on a compensating machine sees (the true growth,
sp2's own, minus the offset in force, plus noise) and advances its counter.

The guard "no model worse than none" ([adaptation] guard_window = 3) must trip
within three probes, raise MODEL_WORSE and ALARM, hold the offset for hold_s, then
ramp it to zero with no step beyond the slew limit.
"""

from __future__ import annotations

import asyncio
import random
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

from compd.core.adaptation import AdaptationSettings, ProbeReading, ProbeStage
from compd.core.faults import Event
from compd.core.output import Status
from compd.infiles import load_model
from compd.runtime.daemon import Daemon
from compd.runtime.driver_setup import build_driver
from compd.runtime.sdnotify import Notifier
from compd.testing import FakeClock
from drivers.base import Driver
from drivers.sim.modbus_server import ModbusSimController
from models.adaptation import AdaptationParams
from tests.faults.clocked_driver import ClockedDriver
from tests.faults.daemon_rig import EventLog, make_config

SLEW_UM_S = 1.0
HOLD_S = 10.0
PROBE_EVERY = 60
CYCLES = 600
LIBRARY = Path(__file__).resolve().parents[2] / "models" / "library" / "sp2.toml"


def _miscalibrated(tmp_path: Path) -> Path:
    """sp2 with every term's gain ×2 and its sign flipped (gain = -2)."""
    text = LIBRARY.read_text(encoding="utf-8").replace("[[terms]]\n", "[[terms]]\ngain = -2.0\n")
    p = tmp_path / "wrong.toml"
    p.write_text(text, encoding="utf-8")
    assert [t.gain for t in load_model(p).terms] == [-2.0, -2.0]
    return p


class Watch(ClockedDriver):
    """The real Modbus driver; before each read the fake clock moves one period and
    the plant publishes the next temperatures (and, every PROBE_EVERY reads, a probe);
    after each cycle the offset in force and the status word are noted."""

    def __init__(self, inner: Driver, clock: FakeClock,
                 plant: Callable[[int], Awaitable[None]]) -> None:
        super().__init__(inner, clock, plant)
        self.offsets: list[float] = []
        self.statuses: list[int] = []

    def note(self, result: Any) -> None:
        self.offsets.append(result.offset_um)
        self.statuses.append(result.status)


async def test_a_model_worse_than_none_is_caught_within_three_probes_and_ramped_to_zero(
        tmp_path: Path) -> None:
    sim = ModbusSimController()
    await sim.start()
    truth = load_model("sp2")
    rng = random.Random(20)
    probes: list[tuple[int, float]] = []  # (read index, the probe's value)
    try:
        await sim.publish({"bearing": 20.0, "ambient": 20.0, "probe_value": 0.0,
                           "probe_counter": 1.0})
        cfg = make_config(sim, tmp_path, time_scale=1.0, slew_um_s=SLEW_UM_S,
                          model=str(_miscalibrated(tmp_path)), overrides={
                              "faults": {"hold_s": HOLD_S},
                              "adaptation": {
                                  "enabled": True, "mode": "apply", "measures": "residual",
                                  "guard_window": 3,
                                  "probe_value": sim.probes["probe_value"].model_dump(),
                                  "probe_counter": sim.probes["probe_counter"].model_dump()}})
        clock = FakeClock(period_s=cfg.real_period_s)
        truth.set_references({"bearing": 20.0, "ambient": 20.0})
        daemon: Daemon | None = None

        async def plant(index: int) -> None:
            if index >= CYCLES:
                assert daemon is not None
                daemon.request_stop()
            bearing = 20.0 + min(index, 300) / 300 * 2.0 + rng.gauss(0.0, 0.01)
            sample = {"bearing": bearing, "ambient": 20.0}
            growth = truth.step(sample)
            values: dict[str, float] = dict(sample)
            if index and index % PROBE_EVERY == 0:
                in_force = (await sim.outputs())["offset"]
                value = growth - in_force + rng.gauss(0.0, 0.2)
                values.update(probe_value=value, probe_counter=1.0 + len(probes) + 1)
                probes.append((index, value))
            await sim.publish(values)

        watch = Watch(build_driver(cfg), clock, plant)
        daemon = Daemon(cfg, driver=watch, notifier=Notifier(None), clock=clock)
        watch.daemon = daemon
        daemon.log = EventLog()
        assert await asyncio.wait_for(daemon.run(), 300.0) == 0
    finally:
        await sim.stop()
    log = daemon.log
    assert isinstance(log, EventLog)
    tripped = [(lvl, f) for lvl, e, f in log.events if e == "model_worse_than_none"]
    assert len(tripped) == 1, log.names()
    level, fields = tripped[0]
    assert level == "error"
    assert abs(fields["error_with_um"]) > abs(fields["error_without_um"])
    # caught within three probes: the status word says so from the cycle after the third
    worse = [k for k, s in enumerate(watch.statuses) if s & Status.MODEL_WORSE]
    assert worse, "the guard never tripped"
    first = worse[0]
    third_probe = probes[2][0]
    assert first <= third_probe + 2, (first, [k for k, _ in probes[:4]])
    assert all(watch.statuses[k] & Status.ALARM for k in worse)
    assert worse == list(range(first, len(watch.statuses)))  # latched
    offsets = watch.offsets
    assert abs(offsets[first - 1]) > 10.0  # the wrong model had pushed the tool off
    # held, then ramped to zero at no more than the slew limit per cycle (1 s)
    steps = [abs(b - a) for a, b in zip(offsets[first - 1:], offsets[first:], strict=False)]
    assert max(steps) <= SLEW_UM_S * cfg.raw.machine.period_s * (1 + 1e-9), max(steps)
    assert offsets[-1] == 0.0
    reached = next(k for k in range(first, len(offsets)) if offsets[k] == 0.0)
    assert reached - first >= HOLD_S  # held before the ramp
    print(f"model worse than none: tripped at cycle {first} (probes at "
          f"{[k for k, _ in probes[:3]]}), offset {offsets[first - 1]:.2f} µm ramped to 0 "
          f"by cycle {reached}, largest step {max(steps):.3f} µm")


# -- the guard alone (compd.core.adaptation), sans I/O --------------------------------------

def _stage(window: int = 3) -> ProbeStage:
    return ProbeStage(AdaptationSettings("shadow", "residual", AdaptationParams(),
                                         guard_window=window), 1)


def _probe(stage: ProbeStage, counter: float, value_um: float, offset_um: float,
           events: list[Event]) -> None:
    stage.step(60.0, ProbeReading(value_um, counter), complete=True, model_um=offset_um,
               terms_um=[offset_um], offset_in_force_um=offset_um, events=events)


def test_a_right_model_with_noisy_probes_and_a_chip_never_trips_the_guard() -> None:
    rng = random.Random(3)
    stage = _stage()
    events: list[Event] = []
    for k in range(200):  # growth 30 µm, compensated to within the probe's noise
        value = rng.gauss(0.0, 0.5) + (50.0 if k in (40, 41) else 0.0)  # two chips
        _probe(stage, float(k), value, 30.0, events)
    assert not stage.model_worse
    assert "model_worse_than_none" not in [e.name for e in events]


def test_three_probes_in_a_row_worse_than_none_trip_it_and_it_stays_tripped() -> None:
    stage = _stage()
    events: list[Event] = []
    _probe(stage, 0.0, 0.0, 0.0, events)  # the baseline
    # growth +10 µm, the offset -20: the tool is 30 µm off instead of 10
    for k in range(1, 3):
        _probe(stage, float(k), 30.0, -20.0, events)
        assert not stage.model_worse
    _probe(stage, 3.0, 30.0, -20.0, events)
    assert stage.model_worse
    tripped = [e for e in events if e.name == "model_worse_than_none"]
    assert len(tripped) == 1 and tripped[0].fields["error_with_um"] == 30.0
    _probe(stage, 4.0, 0.0, 0.0, events)  # a right probe later does not clear it
    again = ProbeStage(stage.settings, 1, stage.export_state())  # nor does a restart
    assert stage.model_worse and again.model_worse


def test_guard_window_0_is_no_guard() -> None:
    stage = _stage(0)
    events: list[Event] = []
    for k in range(10):
        _probe(stage, float(k), 30.0, -20.0, events)
    assert not stage.model_worse
