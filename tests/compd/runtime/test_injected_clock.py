"""One injected clock for the loop and its sinks: with a fake
wall clock, the status page's snapshot and alarms, the last-complete-cycle
metric and the recorder's rows carry its readings, never time.time()'s."""

from __future__ import annotations

import asyncio
from pathlib import Path

from compd.config.loader import load_config
from compd.runtime.clock import Clock, pause
from drivers.base import Quality
from tests.configs import write_config
from tests.harness import memory_daemon

EPOCH = 1.0e9  # 2001: far from today, so a real reading could not pass for it


async def test_the_sinks_stamp_with_the_daemons_wall_clock(tmp_path: Path) -> None:
    p = write_config(tmp_path, "127.0.0.1:1", time_scale=1.0, timeout_s=0.4)
    p.write_text(p.read_text() + "\n[faces.http]\nenabled = true\n", encoding="utf-8")
    cfg = load_config(p)
    daemon, clock, driver = memory_daemon(cfg, epoch=EPOCH, serve_metrics=False)
    task = asyncio.create_task(daemon.run())
    try:
        await clock.cycle_done(1)
        for k in range(1, 5):
            clock.tick()
            await clock.cycle_done(k + 1)
        driver.set("bearing", 20.0, Quality.BAD)  # an invalid channel: a warning, an alarm
        clock.tick()
        await clock.cycle_done(6)
    finally:
        daemon.request_stop()
        assert await task == 0
    board = daemon.status_board
    assert board.snapshot["wall_s"] == EPOCH + 5 * cfg.period_s
    alarms = board.snapshot["alarms"]
    assert alarms and {a["wall_s"] for a in alarms} <= {EPOCH + k * cfg.period_s
                                                        for k in range(6)}
    stamp = daemon.metrics.registry.get_sample_value(
        "compd_last_complete_cycle_timestamp_seconds")
    assert stamp == EPOCH + 4 * cfg.period_s  # the last complete cycle, before the fault


async def test_a_pause_on_the_loops_timer_runs_in_the_callers_task() -> None:
    """Every machine pauses once a cycle: on the event loop's timer the pause is
    a timeout in the caller's task, not a task of its own (asyncio.wait_for's),
    and it ends at a stop request or at its delay."""
    stop = asyncio.Event()
    pausing = asyncio.create_task(pause(Clock(), stop, 3600.0))
    for _ in range(3):
        await asyncio.sleep(0)  # a few loop turns: the pause is waiting
    assert asyncio.all_tasks() == {asyncio.current_task(), pausing}
    stop.set()
    await pausing
    await pause(Clock(), asyncio.Event(), 0.0)  # the delay passed: returns
