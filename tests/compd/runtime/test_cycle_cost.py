"""What a cycle must not cost, on a lockstep run of the real daemon (a thousand
machines in one process run a thousand of these a second): no cyclic garbage
(each cycle's objects are freed by their reference counts, never left for the
collector, whose pauses land in every machine's deadline), no metric set again
to the value it holds, and no per-cycle debug line built when the log is at info."""

from __future__ import annotations

import asyncio
import gc
import io
import logging
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import prometheus_client
import pytest
import structlog

from compd.config.loader import load_config
from compd.faces import logs
from compd.faces.logs import logs_at
from compd.faces.telemetry import configure_logging
from compd.runtime.daemon import Daemon
from compd.testing import MemoryDriver, SteppedClock
from tests.configs import write_config
from tests.harness import memory_daemon


@pytest.fixture(autouse=True)
def _info_logging() -> Iterator[None]:
    level = logs._least_level[0]
    configure_logging(json=True, level="info", stream=io.StringIO())
    yield
    logs._least_level[0] = level
    structlog.reset_defaults()
    root = logging.getLogger()
    for handler in [h for h in root.handlers if h.get_name() == "compd"]:
        root.removeHandler(handler)
    root.setLevel(logging.WARNING)


async def _run(daemon: Daemon, clock: SteppedClock, driver: MemoryDriver,
               cycles: range) -> None:
    for k in cycles:
        driver.set("bearing", 20.0 + 0.001 * k)
        clock.tick()
        await clock.cycle_done(k + 1)


async def _started(tmp_path: Path) -> tuple[Daemon, SteppedClock, MemoryDriver,
                                            asyncio.Task[int]]:
    cfg = load_config(write_config(tmp_path, "127.0.0.1:1", time_scale=1.0, timeout_s=0.4))
    daemon, clock, driver = memory_daemon(cfg, epoch=1.7e9)
    task = asyncio.create_task(daemon.run())
    await clock.cycle_done(1)
    await _run(daemon, clock, driver, range(1, 30))  # past the start's one-off work
    return daemon, clock, driver, task


async def test_a_cycle_leaves_no_cyclic_garbage(tmp_path: Path) -> None:
    daemon, clock, driver, task = await _started(tmp_path)
    daemon.loop.gc_policy = None  # no collection of its own between cycles
    gc.collect()
    gc.disable()
    try:
        gc.set_debug(gc.DEBUG_SAVEALL)  # what a collection finds stays in gc.garbage
        await _run(daemon, clock, driver, range(30, 130))
        found = gc.collect()
        kinds = sorted({type(o).__name__ for o in gc.garbage})
    finally:
        gc.set_debug(0)
        gc.garbage.clear()
        gc.enable()
    daemon.request_stop()
    assert await task == 0
    assert found == 0, f"100 cycles left {found} objects in cycles: {kinds[:20]}"


async def test_unchanged_metrics_are_not_set_again(tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    daemon, clock, driver, task = await _started(tmp_path)
    sets: list[tuple[str, float, float]] = []  # (gauge, value held, value set)
    real = prometheus_client.Gauge.set

    def counted(self: prometheus_client.Gauge, value: float) -> None:
        sets.append((self._name, self._value.get(), value))
        real(self, value)

    monkeypatch.setattr(prometheus_client.Gauge, "set", counted)
    for k in range(30, 40):  # the inputs stand still (the model's output still moves)
        clock.tick()
        await clock.cycle_done(k + 1)
    assert sets, "the offset and the time of the last complete cycle move"
    assert [s for s in sets if s[1] == s[2]] == []  # never set to the value it holds
    names = {name for name, _, _ in sets}
    assert not names & {"compd_channel_temperature_celsius", "compd_channel_valid",
                        "compd_fault_state"}
    sets.clear()
    driver.set("bearing", 25.0)
    clock.tick()
    await clock.cycle_done(41)
    assert ("compd_channel_temperature_celsius", 25.0) in [(n, v) for n, _, v in sets]
    assert daemon.metrics.registry.get_sample_value(
        "compd_channel_temperature_celsius", {"channel": "bearing"}) == 25.0
    daemon.request_stop()
    assert await task == 0


async def test_no_per_cycle_debug_line_is_built_at_info(tmp_path: Path) -> None:
    assert not logs_at(logging.DEBUG) and logs_at(logging.INFO)
    daemon, clock, driver, task = await _started(tmp_path)
    asked: list[str] = []
    real = daemon.journal.log

    class Watched:
        def __getattr__(self, name: str) -> Any:
            asked.append(name)
            return getattr(real, name)

    daemon.journal.log = Watched()
    await _run(daemon, clock, driver, range(30, 40))
    daemon.journal.log = real
    daemon.request_stop()
    assert await task == 0
    assert "debug" not in asked
