"""The injected clock drives the daemon and is never bypassed: with
`compd.testing.SteppedClock` as its clock and its sleep, and a fake wall
clock, the real `Daemon` runs exactly one cycle per tick, stamps its records
and its health evidence with the clocks it was given, and never reads the
real ones for them."""

from __future__ import annotations

import asyncio
from pathlib import Path

import numpy as np
import pytest

from compd.config.loader import load_config
from compd.runtime.checkpoint import CHECKPOINT_NAME, load_checkpoint
from compd.runtime.recorder import read_samples
from compd.testing import SteppedClock
from tests.configs import write_config
from tests.harness import memory_daemon

EPOCH = 1.7e9  # the fake wall clock's reading at monotonic 0


async def test_stepped_clock_wakes_a_sleeper_only_at_its_deadline() -> None:
    clock = SteppedClock(period_s=0.1, start_s=5.0)
    nap = asyncio.ensure_future(clock.sleep(0.3))
    await clock.cycle_done(1)
    assert clock.sleeps == 1 and clock.sleeping == 1
    for _ in range(2):
        clock.tick()
        await asyncio.sleep(0)
        assert not nap.done()
    clock.tick()  # 5.0 + 3 * 0.1, on the grid: no rounding leaves it short
    await nap
    assert clock() == 5.0 + 3 * 0.1 and clock.sleeping == 0
    await clock.sleep(0.0)  # returns at once, not counted
    assert clock.sleeps == 1
    with pytest.raises(ValueError, match="does not go back"):
        clock.set(1.0)


async def test_the_daemon_runs_one_cycle_per_tick_on_the_clocks_it_was_given(
        tmp_path: Path) -> None:
    cfg = load_config(write_config(tmp_path, "127.0.0.1:1", time_scale=1.0, timeout_s=0.4))
    daemon, clock, driver = memory_daemon(cfg, epoch=EPOCH)
    task = asyncio.create_task(daemon.run())
    await clock.cycle_done(1)
    for k in range(1, 40):
        driver.set("bearing", 20.0 + 0.05 * k)
        clock.tick()
        await clock.cycle_done(k + 1)
        assert daemon.loop.cycles == k + 1  # one cycle per tick, however slow the machine
    daemon.request_stop()
    assert await task == 0
    assert daemon.loop.overruns == 0
    # the health evidence and the records: the given clocks, not time.time()/monotonic()
    assert daemon.checkpoint.last_complete == (EPOCH + 39 * cfg.period_s, 39 * cfg.period_s)
    # the checkpoint's time is its last cycle's, on the daemon's clocks: a restart
    # judges the state's age by it
    saved = load_checkpoint(tmp_path / "state" / CHECKPOINT_NAME)
    last = daemon.loop.last_result
    assert saved is not None and last is not None and saved["sequence"] == last.sequence
    assert (saved["saved_wall_s"], saved["saved_mono_s"]) == (last.wall_s, last.wall_s - EPOCH)
    rows = read_samples(tmp_path / "state" / "samples.sqlite")
    assert rows["seq"].size == daemon.loop.cycles
    assert np.array_equal(rows["wall_s"], EPOCH + rows["mono_s"])
    assert np.array_equal(rows["mono_s"][:40], np.arange(40) * cfg.period_s)
