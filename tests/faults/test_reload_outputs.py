"""A reload that changes where or how far the offset may go, end to end: the
daemon in lockstep (`tests.harness`, the fake clock) against the real
simulated controller servers on 127.0.0.1, the invariants (`invariants`:
never a step faster than the slew limit from what the controller holds)
checked on every cycle.

- `limit_um` lowered below the offset compd wrote: the offset in the register
  ramps into the new limit at the slew limit (never a jump, never held), the
  status word tells SLEWING and no alarm, the status page says why;
- the offset moved to other memory of the same controller: refused
  (``reload_failed``, key ``output.offset``); the old address stays in force
  and keeps being written, the heartbeat counts on, the new address is never
  written.
"""

from __future__ import annotations

import itertools
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest

from compd.core.output import Status
from drivers.sim.base import SimController
from drivers.sim.machine import SimMachine
from drivers.sim.programs import constant
from drivers.sim.registry import make_sim_controller
from tests.configs import lockstep_config, write_doc
from tests.harness import Lockstep

PERIOD_S = 1.0
SLEW_UM_S = 0.5
LIMIT_UM = 100.0
#: the offset written before the reload, and the limit the reload lowers to
WRITTEN_UM = 21.55
LOWERED_UM = 20.0
#: per protocol: a writable address of its simulated controller, not the offset's
ELSEWHERE = {"modbus": "enc_f32_little", "s7": "enc_real"}


class Rig:
    def __init__(self, lockstep: Lockstep, doc: dict[str, Any]) -> None:
        self.lockstep = lockstep
        self.doc = doc

    @property
    def sim(self) -> SimController:
        return self.lockstep.machine.controller

    async def outputs(self) -> dict[str, float]:
        return await self.sim.outputs()

    async def reload(self, **output: Any) -> None:
        """Write the config with `output` changed, SIGHUP, and run one period (the
        prepared reload, if any, is swapped in before that period's cycle)."""
        self.doc["output"].update(output)
        write_doc(self.doc, self.lockstep.config_path)
        daemon = self.lockstep.daemon
        assert daemon is not None
        daemon.request_reload()
        assert daemon.reloader.task is not None
        await daemon.reloader.task
        await self.lockstep.step()

    def events(self, name: str) -> list[dict[str, Any]]:
        return [f for _, e, f in self.lockstep.logs[-1].events if e == name]


async def _rig(protocol: str, tmp_path: Path) -> AsyncIterator[Rig]:
    sim = make_sim_controller(protocol)
    await sim.start()
    machine = SimMachine(sim, program=constant(9_000.0, 8.0, 1.0), period_s=PERIOD_S,
                         repeat=False)
    doc = lockstep_config(sim, tmp_path, model="sp2", period_s=PERIOD_S, limit_um=LIMIT_UM,
                          slew_um_s=SLEW_UM_S)
    doc["faces"] = {"http": {"enabled": True}}  # the status page's snapshot, not served
    lockstep = Lockstep(machine, write_doc(doc, tmp_path / "compd.toml"))
    try:
        yield Rig(lockstep, doc)
    finally:
        await lockstep.close()
        await sim.stop()


@pytest.fixture
async def modbus(tmp_path: Path) -> AsyncIterator[Rig]:
    async for rig in _rig("modbus", tmp_path):
        yield rig


@pytest.fixture(params=sorted(ELSEWHERE))
async def any_rig(request: pytest.FixtureRequest, tmp_path: Path) -> AsyncIterator[Rig]:
    async for rig in _rig(request.param, tmp_path):
        yield rig


async def _warm_to(rig: Rig, monkeypatch: pytest.MonkeyPatch, offset_um: float) -> float:
    """The bearing 2.5 K warm (sp2 wants about +40 µm): step until the offset the
    controller holds is at least `offset_um` (slewing up at SLEW_UM_S)."""
    machine = rig.lockstep.machine
    hot = {**machine.plant.sensors(), "bearing": 22.5, "ambient": 20.0}
    monkeypatch.setattr(machine.plant, "sensors", lambda: hot)
    for _ in range(int(2 * offset_um / (SLEW_UM_S * PERIOD_S)) + 10):
        await rig.lockstep.step()
        held = (await rig.outputs())["offset"]
        if held >= offset_um:
            return held
    raise AssertionError(f"the offset never reached {offset_um} µm")


async def test_a_lowered_limit_ramps_the_register_into_it_at_the_slew_limit(
        modbus: Rig, monkeypatch: pytest.MonkeyPatch) -> None:
    rig = modbus
    daemon = await rig.lockstep.start()
    before = await _warm_to(rig, monkeypatch, WRITTEN_UM)
    await rig.reload(limit_um=LOWERED_UM)
    assert daemon.reloader.reloads == 1 and daemon.running.cfg.raw.output.limit_um == LOWERED_UM
    offsets, words = [before], []
    page = daemon.status_board.snapshot
    # the model still asks for more than the lowered limit: "limited" (not in force)
    assert page["state"] == "limited" and "beyond limit_um" in page["why"]
    assert page["offset_um"] > page["limit_um"] == LOWERED_UM
    while True:
        out = await rig.outputs()
        offsets.append(out["offset"])
        words.append(int(out["status"]))
        if len(offsets) > 10:
            break
        await rig.lockstep.step()
    # down from what compd wrote, at the slew limit, never a jump, then at the limit
    steps = [a - b for a, b in itertools.pairwise(offsets)]
    assert all(-1e-4 <= s <= SLEW_UM_S * PERIOD_S + 1e-4 for s in steps), offsets
    assert offsets[1] == pytest.approx(before - SLEW_UM_S * PERIOD_S, abs=1e-4)
    assert offsets[-1] == pytest.approx(LOWERED_UM, abs=1e-4)
    # the status word: compensating, slew-limited while it comes in, never held, no alarm
    for word in words:
        assert word & Status.OK and not word & (Status.OFFSET_HELD | Status.ALARM), words
    ramping = [w for o, w in zip(offsets[1:], words, strict=True) if o > LOWERED_UM + 1e-4]
    assert len(ramping) >= 3 and all(w & Status.SLEWING for w in ramping), (offsets, words)
    assert not rig.events("readback_out_of_range")
    (beyond,) = rig.events("offset_beyond_limit")
    assert beyond["offset_um"] == pytest.approx(before, abs=1e-4)
    assert beyond["limit_um"] == LOWERED_UM
    assert len(rig.events("offset_within_limit")) == 1
    page = daemon.status_board.snapshot
    assert page["state"] == "limited" and "beyond limit_um" not in page["why"]
    assert await rig.lockstep.stop() == 0


async def test_a_reload_moving_the_offset_is_refused_and_the_old_address_kept(
        any_rig: Rig, monkeypatch: pytest.MonkeyPatch) -> None:
    rig = any_rig
    sim: Any = rig.sim
    protocol = sim.protocol
    elsewhere = ELSEWHERE[protocol]
    daemon = await rig.lockstep.start()
    await _warm_to(rig, monkeypatch, 5.0)
    moved = sim.encodings[elsewhere].model_dump()
    await rig.reload(offset=moved)
    (failed,) = rig.events("reload_failed")
    assert failed["key"] == "output.offset" and "restart compd" in failed["reason"]
    assert daemon.reloader.reloads == 0 and not rig.events("reload_succeeded")
    # the old address stays in force and written: the offset follows the model up at
    # the slew limit, the heartbeat counts every cycle; the other address is untouched
    seen = [await rig.outputs()]
    for _ in range(5):
        await rig.lockstep.step()
        seen.append(await rig.outputs())
    for a, b in itertools.pairwise(seen):
        assert b["offset"] == pytest.approx(a["offset"] + SLEW_UM_S * PERIOD_S, abs=1e-4)
        assert b["heartbeat"] == a["heartbeat"] + 1
        assert int(b["status"]) & Status.OK
    if protocol == "modbus":
        untouched = (await sim.read_values([elsewhere]))[elsewhere]
    else:
        untouched = await sim.read_back(elsewhere)
    assert untouched == 0.0
    assert await rig.lockstep.stop() == 0


async def test_a_restart_with_a_lowered_limit_ramps_the_register_into_it(
        modbus: Rig, monkeypatch: pytest.MonkeyPatch) -> None:
    """The same through a restart: the checkpoint's offset (compd's own) beyond
    the new limit is not held as foreign, it ramps in at the slew limit."""
    rig = modbus
    await rig.lockstep.start()
    before = await _warm_to(rig, monkeypatch, WRITTEN_UM)
    assert await rig.lockstep.stop() == 0  # shutdown "hold": the register keeps it
    rig.doc["output"]["limit_um"] = LOWERED_UM
    write_doc(rig.doc, rig.lockstep.config_path)
    await rig.lockstep.start()  # its first cycle (READY) already ramps
    offsets = [before, (await rig.outputs())["offset"]]
    for _ in range(8):
        await rig.lockstep.step()
        offsets.append((await rig.outputs())["offset"])
    steps = [a - b for a, b in itertools.pairwise(offsets)]
    assert all(-1e-4 <= s <= SLEW_UM_S * PERIOD_S + 1e-4 for s in steps), offsets
    assert offsets[1] < before and offsets[-1] == pytest.approx(LOWERED_UM, abs=1e-4)
    names = rig.lockstep.logs[-1].names()
    assert "readback_out_of_range" not in names and "offset_beyond_limit" in names
    assert await rig.lockstep.stop() == 0
