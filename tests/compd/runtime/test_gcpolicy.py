"""The full garbage collection runs between cycles, once per interval
(`compd.runtime.gcpolicy`), never by the allocator inside a cycle."""

from __future__ import annotations

import asyncio
import gc
from collections.abc import Iterator
from pathlib import Path

import pytest

from compd.config.loader import load_config
from compd.runtime.gcpolicy import NEVER, GcPolicy
from tests.configs import write_config
from tests.harness import memory_daemon


class Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def thresholds() -> Iterator[tuple[int, int, int]]:
    saved = gc.get_threshold()
    yield saved
    gc.set_threshold(*saved)


def make(clock: Clock, collected: list[int]) -> GcPolicy:
    return GcPolicy(full_every_s=60.0, min_slack_s=0.2, clock=clock,
                    collect=collected.append)


def test_install_leaves_the_young_generations_and_stops_automatic_full_collections(
        thresholds: tuple[int, int, int]) -> None:
    policy = make(Clock(), [])
    policy.install()
    young, middle, _ = thresholds
    assert gc.get_threshold() == (young, middle, NEVER)
    policy.install()  # a second machine of the process
    policy.uninstall()
    assert gc.get_threshold() == (young, middle, NEVER)  # one machine still runs
    policy.uninstall()
    assert gc.get_threshold() == thresholds


def test_full_collection_only_when_due_and_in_slack(
        thresholds: tuple[int, int, int]) -> None:
    clock = Clock()
    collected: list[int] = []
    policy = make(clock, collected)
    assert not policy.after_cycle(0.9)  # not installed: CPython's own rules
    policy.install()
    clock.now += 59.0
    assert not policy.after_cycle(0.9)  # not due yet
    clock.now += 1.0
    assert not policy.after_cycle(0.1)  # due, but the next deadline is too near
    assert collected == []
    assert policy.after_cycle(0.5)
    assert collected == [2]
    assert not policy.after_cycle(0.9)  # once per interval for the whole process
    clock.now += 60.0
    assert policy.after_cycle(0.9)
    assert collected == [2, 2] and policy.collections == 2
    policy.uninstall()


def test_overdue_collection_runs_without_slack(thresholds: tuple[int, int, int]) -> None:
    """A loop that never has the slack still collects, so cyclic garbage stays bounded."""
    clock = Clock()
    collected: list[int] = []
    policy = make(clock, collected)
    policy.install()
    clock.now += 119.0
    assert not policy.after_cycle(0.0)
    clock.now += 1.0
    assert policy.after_cycle(0.0)
    assert collected == [2]
    policy.uninstall()


def test_bad_settings_refused() -> None:
    with pytest.raises(ValueError):
        GcPolicy(full_every_s=0.0)
    with pytest.raises(ValueError):
        GcPolicy(min_slack_s=-1.0)


async def test_the_daemon_collects_between_cycles_once_per_interval(
        tmp_path: Path, thresholds: tuple[int, int, int]) -> None:
    """The daemon installs the policy for its run (no automatic full collection
    while it cycles), asks it after every cycle, and gives the thresholds back."""
    cfg = load_config(write_config(tmp_path, "127.0.0.1:1", time_scale=1.0, timeout_s=0.4))
    daemon, clock, _driver = memory_daemon(cfg, epoch=1.7e9)
    collected: list[tuple[int, float]] = []
    daemon.loop.gc_policy = GcPolicy(full_every_s=60.0, clock=clock,
                                     collect=lambda gen: collected.append((gen, clock())))
    task = asyncio.create_task(daemon.run())
    await clock.cycle_done(1)
    assert gc.get_threshold()[2] == NEVER
    for k in range(1, 130):
        clock.tick()
        await clock.cycle_done(k + 1)
    daemon.request_stop()
    assert await task == 0
    assert collected == [(2, 60.0), (2, 120.0)]  # after the cycles of 60 s and 120 s
    assert gc.get_threshold() == thresholds
