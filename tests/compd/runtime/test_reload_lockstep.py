"""A SIGHUP reload never costs a cycle, tested deterministically: the daemon
in-process in lockstep (`tests.harness`) against the simulated Modbus
controller on 127.0.0.1, the reload's preparation (`compd.runtime.reload.prepare`,
which the daemon runs in a worker thread) held on a gate.

While the new config is being read and validated the loop keeps its
deadlines: N machine periods stepped are N cycles run, on the old config.
Released, the new config is swapped in between two cycles (the first cycle
after the swap already runs on it) and the offset the controller holds never
moves faster than the slew limit (the old one before, the new one after).

The real SIGHUP path (signal handler, a real process, real time) is in
test_reload.py; it asserts only what a loaded machine cannot change.
"""

from __future__ import annotations

import asyncio
import itertools
import threading
from collections.abc import AsyncIterator, Iterator
from pathlib import Path
from typing import Any

import pytest

import compd.runtime.reload as reload_module
from compd.config.loader import LoadedConfig
from compd.runtime.daemon import Daemon
from compd.runtime.reload import Changes
from drivers.sim.machine import SimMachine
from drivers.sim.modbus_server import ModbusSimController
from drivers.sim.programs import constant
from tests.configs import lockstep_config, write_doc
from tests.harness import Lockstep

PERIOD_S = 1.0         # the period sp2 and sp3 were identified at
OLD_SLEW_UM_S = 1.0
NEW_SLEW_UM_S = 0.5
HELD_PERIODS = 7       # periods stepped while the reload is being prepared


class Gate:
    """Wraps `compd.runtime.reload.prepare`: each call says it entered, then
    waits (in the daemon's worker thread) until the test opens the gate."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch) -> None:
        self.calls = 0
        self.entered = threading.Event()
        self.opened = threading.Event()
        original = reload_module.prepare

        def held(old: LoadedConfig) -> tuple[LoadedConfig, Changes]:
            self.calls += 1
            self.entered.set()
            # generous bound: a test that forgot to open the gate fails, never hangs
            if not self.opened.wait(120.0):
                raise TimeoutError("the test never opened the reload gate")
            return original(old)

        monkeypatch.setattr(reload_module, "prepare", held)

    async def wait_entered(self) -> None:
        """Until the daemon's preparation is inside `prepare` (an event)."""
        assert await asyncio.to_thread(self.entered.wait, 120.0), "no reload began"

    def close(self) -> None:
        self.entered.clear()
        self.opened.clear()

    def open(self) -> None:
        self.opened.set()


@pytest.fixture
def gate(monkeypatch: pytest.MonkeyPatch) -> Iterator[Gate]:
    g = Gate(monkeypatch)
    try:
        yield g
    finally:
        g.open()  # a failed test's worker thread ends now, not in two minutes


@pytest.fixture
async def rig(tmp_path: Path) -> AsyncIterator[Lockstep]:
    sim = ModbusSimController()
    await sim.start()
    machine = SimMachine(sim, program=constant(9_000.0, 8.0, 1.0), period_s=PERIOD_S,
                         repeat=False)
    doc = lockstep_config(sim, tmp_path, model="sp2", period_s=PERIOD_S, limit_um=100.0,
                          slew_um_s=OLD_SLEW_UM_S)
    doc["state"]["checkpoint_every"] = 20
    r = Lockstep(machine, write_doc(doc, tmp_path / "compd.toml"))
    try:
        yield r
    finally:
        await r.close()
        await sim.stop()


async def _offsets(rig: Lockstep, periods: int, into: list[float]) -> None:
    """Step `periods` periods, keeping the offset the controller holds after each."""
    for _ in range(periods):
        await rig.step()
        into.append((await rig.machine.controller.outputs())["offset"])


async def _prepared(daemon: Daemon) -> None:
    """Until the reload's preparation task is done (it left its result for the loop)."""
    task = daemon.reloader.task
    assert task is not None
    await task


def _model_file(daemon: Daemon) -> str | None:
    section = daemon.running.cfg.raw.model
    return None if section is None else section.file


def _events(rig: Lockstep, name: str) -> list[dict[str, Any]]:
    return [fields for _, event, fields in rig.logs[-1].events if event == name]


async def test_a_reload_being_prepared_costs_no_cycle_and_swaps_under_the_slew_limit(
        rig: Lockstep, gate: Gate, monkeypatch: pytest.MonkeyPatch) -> None:
    daemon = await rig.start()
    offsets: list[float] = []
    # the bearing 2.5 K warmer from now on (sp2 wants about +40 µm): the daemon
    # follows under its slew limit
    hot = {**rig.machine.plant.sensors(), "bearing": 22.5, "ambient": 20.0}
    monkeypatch.setattr(rig.machine.plant, "sensors", lambda: hot)
    await _offsets(rig, 15, offsets)
    assert offsets[-1] >= 10.0
    # another model (same channels) and a slower slew limit
    text = rig.config_path.read_text()
    rig.config_path.write_text(text.replace('file = "sp2"', 'file = "sp3"')
                               .replace(f"slew_um_s = {OLD_SLEW_UM_S}",
                                        f"slew_um_s = {NEW_SLEW_UM_S}"))
    daemon.request_reload()
    await gate.wait_entered()

    cycles, at_hup = daemon.loop.cycles, len(offsets)
    await _offsets(rig, HELD_PERIODS, offsets)
    # every period stepped ran its cycle, on the old config, on time
    assert daemon.loop.cycles == cycles + HELD_PERIODS
    assert daemon.reloader.reloads == 0 and _model_file(daemon) == "sp2"
    assert daemon.loop.overruns == 0
    assert offsets[-1] - offsets[at_hup - 1] == pytest.approx(
        HELD_PERIODS * OLD_SLEW_UM_S * PERIOD_S, abs=1e-3)  # still slewing at the old limit

    gate.open()
    await _prepared(daemon)
    assert daemon.reloader.reloads == 0  # prepared, not yet swapped: the loop swaps
    swapped_at = len(offsets)
    await _offsets(rig, 1, offsets)
    # the swap came between two cycles: one period, one cycle, and that cycle ran
    # on the new config
    assert daemon.loop.cycles == cycles + HELD_PERIODS + 1
    assert daemon.reloader.reloads == 1 and _model_file(daemon) == "sp3"
    await _offsets(rig, 20, offsets)
    assert daemon.loop.overruns == 0

    (done,) = _events(rig, "reload_succeeded")
    assert "model.file" in done["changed"] and "output.slew_um_s" in done["changed"]
    assert "model" in done["restarted"] and done["filters"] == "restart_at_steady_state"
    assert "controller" not in done["restarted"]  # same endpoint and addresses: same link
    steps = [abs(b - a) for a, b in itertools.pairwise(offsets)]
    assert max(steps[:swapped_at - 1]) <= OLD_SLEW_UM_S * PERIOD_S + 1e-3
    assert max(steps[swapped_at - 1:]) <= NEW_SLEW_UM_S * PERIOD_S + 1e-3
    assert await rig.stop() == 0
    (stopped,) = _events(rig, "daemon_stopped")
    assert stopped["reloads"] == 1 and stopped["overruns"] == 0


async def test_a_storm_of_reloads_misses_no_cycle(
        rig: Lockstep, gate: Gate) -> None:
    """Ten reloads, each held for a different number of periods (0 to 3): every
    period stepped is one cycle, every reload is swapped in, the unchanged model
    carries its filters over."""
    daemon = await rig.start()
    await rig.step(5)
    cycles, stepped = daemon.loop.cycles, 0
    for i in range(10):
        gate.close()
        text = rig.config_path.read_text()
        rig.config_path.write_text(text.replace(f"checkpoint_every = {20 + i}",
                                                f"checkpoint_every = {21 + i}"))
        daemon.request_reload()
        await gate.wait_entered()
        await rig.step(i % 4)
        stepped += i % 4
        assert daemon.reloader.reloads == i
        gate.open()
        await _prepared(daemon)
        await rig.step()
        stepped += 1
        assert daemon.reloader.reloads == i + 1
        assert daemon.running.cfg.raw.state.checkpoint_every == 21 + i
    assert daemon.loop.cycles == cycles + stepped and daemon.loop.overruns == 0
    done = _events(rig, "reload_succeeded")
    assert len(done) == 10 and gate.calls == 10
    assert all(d["filters"] == "carried_over" and d["restarted"] == []
               and d["changed"] == ["state.checkpoint_every"] for d in done)
    assert await rig.stop() == 0
    (stopped,) = _events(rig, "daemon_stopped")
    assert stopped["reloads"] == 10 and stopped["overruns"] == 0


async def test_a_reload_asked_for_during_another_reads_the_file_again(
        rig: Lockstep, gate: Gate) -> None:
    """A second SIGHUP while the first reload is being prepared: the file may
    have changed after it was read, so it is read again; one swap, of the
    last version, and no cycle missed meanwhile."""
    daemon = await rig.start()
    original = rig.config_path.read_text()
    rig.config_path.write_text(original.replace("checkpoint_every = 20",
                                                "checkpoint_every = 21"))
    daemon.request_reload()
    await gate.wait_entered()
    rig.config_path.write_text(original.replace("checkpoint_every = 20",
                                                "checkpoint_every = 22"))
    daemon.request_reload()  # served after the first
    cycles = daemon.loop.cycles
    await rig.step(3)
    assert daemon.loop.cycles == cycles + 3 and daemon.reloader.reloads == 0
    gate.open()
    await _prepared(daemon)
    await rig.step()
    assert gate.calls == 2 and daemon.reloader.reloads == 1
    assert daemon.running.cfg.raw.state.checkpoint_every == 22
    assert daemon.loop.cycles == cycles + 4 and daemon.loop.overruns == 0
    assert await rig.stop() == 0
