"""A coarse offset encoding, through the wire: the offset in an int16 holding register
at scale 10 (1 count = 10 µm) of the simulated Modbus controller, the
in-process daemon on the fake clock (one machine second a cycle, exactly)
and the sp2 model on a bearing that drifts slowly up and back down, read
through its 0.1 K register with sensor noise. A count is written only when
the model is a whole count from the one in force, so the register never
goes 1→2→1→2 on consecutive cycles.

Figures (printed): the largest step at the tool (one count, 10 µm), how
often the register changed, how often it turned straight back, and the
largest distance between the register and the model.
"""

from __future__ import annotations

import asyncio
import itertools
import math
import random
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

from compd.runtime.daemon import Daemon
from compd.runtime.driver_setup import build_driver
from compd.runtime.sdnotify import Notifier
from compd.testing import FakeClock
from drivers.base import Driver
from drivers.sim.modbus_server import UNIT, ModbusSimController
from tests.configs import make_config
from tests.faults.clocked_driver import ClockedDriver
from tests.harness import EventLog

COUNT_UM = 10.0
ADDRESS = 20
OFFSET = {"unit": UNIT, "kind": "holding", "address": ADDRESS, "type": "int16",
          "scale": COUNT_UM}
SLEW_UM_S = 1.0
CYCLES = 1600


class Watch(ClockedDriver):
    """The real Modbus driver; before each read the fake clock moves one
    (real) period, the offset register (what the last cycle left in force,
    straight from the simulated controller's memory) is noted beside the
    last cycle's model output, and the plant publishes the next temperatures."""

    def __init__(self, inner: Driver, sim: ModbusSimController, clock: FakeClock,
                 plant: Callable[[int], Awaitable[None]]) -> None:
        super().__init__(inner, clock, plant)
        self.sim = sim
        #: per cycle: the register after it (counts) and its model output (µm)
        self.counts: list[int] = []
        self.models: list[float] = []

    def note(self, result: Any) -> None:
        [raw] = self.sim.raw("holding", ADDRESS, 1)
        self.counts.append(raw - 65536 if raw >= 32768 else raw)
        self.models.append(math.nan if result.model_um is None else result.model_um)


def bearing_c(k: int, rng: random.Random) -> float:
    """Up 2.5 K over the first half, back down over the second (≈ 0.003 K/s),
    with 0.03 K of sensor noise."""
    half = CYCLES / 2
    rise = 2.5 * (k / half if k <= half else (CYCLES - k) / half)
    return 20.0 + rise + rng.gauss(0.0, 0.03)


async def test_int16_x10_offset_never_chatters(tmp_path: Path) -> None:
    sim = ModbusSimController()
    await sim.start()
    try:
        await sim.publish({"bearing": 20.0, "ambient": 20.0})
        cfg = make_config(sim, tmp_path, time_scale=1.0, slew_um_s=SLEW_UM_S,
                          overrides={"output": {"offset": dict(OFFSET)}})
        assert cfg.offset_quantum_um == COUNT_UM
        clock = FakeClock(period_s=cfg.real_period_s)
        rng = random.Random(24)
        daemon: Daemon | None = None

        async def plant(index: int) -> None:
            if index >= CYCLES:
                assert daemon is not None
                daemon.request_stop()
            await sim.publish({"bearing": bearing_c(index, rng), "ambient": 20.0})

        watch = Watch(build_driver(cfg), sim, clock, plant)
        daemon = Daemon(cfg, driver=watch, notifier=Notifier(None), clock=clock)
        watch.daemon = daemon
        daemon.journal.log = EventLog()
        assert await asyncio.wait_for(daemon.run(), 300.0) == 0
    finally:
        await sim.stop()
    log = daemon.journal.log
    assert isinstance(log, EventLog)
    names = log.names()
    counts, models = watch.counts, watch.models
    assert len(counts) == CYCLES, len(counts)
    assert "readback_mismatch" not in names, names
    top = max(m for m in models if math.isfinite(m))
    assert top > 3.5 * COUNT_UM, top  # the model crossed several counts

    steps = [b - a for a, b in itertools.pairwise(counts)]
    changes = [(k, s) for k, s in enumerate(steps) if s]
    turned = [(k, s) for k, s in enumerate(steps[1:], start=1) if s and s == -steps[k - 1]]
    flaps = [k for k, (a, b, c) in enumerate(zip(counts, counts[1:], counts[2:], strict=False))
             if a == c != b]
    largest_um = max((abs(s) for s in steps), default=0) * COUNT_UM
    # the register against the model output of the same cycle
    gap_um = max(abs(c * COUNT_UM - m) for c, m in zip(counts[50:], models[50:], strict=False)
                 if math.isfinite(m))
    print(f"int16 x10 µm: {len(counts)} cycles, largest step at the tool {largest_um:g} µm, "
          f"{len(changes)} count changes, {len(turned)} turned straight back, "
          f"{len(flaps)} a→b→a, register vs model at most {gap_um:.2f} µm, "
          f"model up to {top:.2f} µm")
    assert not flaps, flaps[:10]
    assert not turned, turned[:10]
    assert largest_um == COUNT_UM
    # up one count at a time with the heat and down again: once per count each way
    ups = sum(1 for _, s in changes if s > 0)
    downs = sum(1 for _, s in changes if s < 0)
    assert 3 <= ups <= top / COUNT_UM and ups - 1 <= downs <= ups, (ups, downs)
    # within one count of the wanted value, which follows the model and its
    # sample-to-sample noise (0.1 K of bearing is 1.8 µm of sp2)
    assert gap_um < 1.25 * COUNT_UM, gap_um
