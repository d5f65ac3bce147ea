"""The machine as a shop runs it, end to end: the in-process daemon on the
stepped clock against the real simulated Modbus controller, every write
checked by the output invariants (|u| ≤ limit, |Δu| ≤ slew·Δt against what the
controller holds, heartbeat).

- the PLC withholds permission (``[output] update_permitted`` at holding 20):
  the offset in force stands still while the model steps, health says
  ``waiting_for_permission``, and the permit's return ramps the change in;
- the PLC pulses ``[output] rezero`` (holding 21) at touch-off, and an
  operator runs ``compd rezero --state-dir``: each takes the present
  prediction as the new zero, ramped at the slew limit, kept over a restart;
- a warm machine, no checkpoint, a calibration reference: the first offset
  the daemon aims at is the growth the machine already has.
"""

from __future__ import annotations

import asyncio
import json
from itertools import pairwise
from pathlib import Path
from typing import Any

from compd.cli import main as cli
from compd.core.health import Cause
from drivers.sim.modbus_server import PLC, ModbusSimController
from tests.configs import make_config
from tests.faults.daemon_rig import DaemonRig
from tests.faults.invariants import Invariants, invariants

__all__ = ["invariants"]  # the autouse fixture, imported to be active here

SLEW = 2.0
REF = {"bearing": 20.0, "ambient": 20.0}


def _overrides(**extra: Any) -> dict[str, Any]:
    out: dict[str, Any] = {
        "output": {"update_permitted": PLC["plc_update_permitted"].model_dump(),
                   "rezero": PLC["plc_rezero"].model_dump()},
        "model": {"reference": REF}}
    out.update(extra)
    return out


async def _rig(tmp_path: Path, inv: Invariants, bearing: list[float]) -> tuple[
        ModbusSimController, DaemonRig]:
    sim = ModbusSimController()
    await sim.start()
    await sim.publish({"bearing": bearing[0], "ambient": 20.0, "plc_update_permitted": 1})
    cfg = make_config(sim, tmp_path, time_scale=1.0, slew_um_s=SLEW, overrides=_overrides())

    async def plant(_index: int, _t: float) -> None:
        await sim.publish({"bearing": bearing[0], "ambient": 20.0})

    return sim, DaemonRig(sim, cfg, inv, plant, stepped=True)


def _offset(rig: DaemonRig) -> float:
    r = rig.daemon.loop.last_result
    return r.stage_um if r is not None else float("nan")


def _steps(inv: Invariants, since: int = 0) -> float:
    """The largest change of the written offset between two cycles (µm)."""
    sent = [c.written["offset"] for c in inv.log()[since:] if "offset" in c.written]
    return max((abs(b - a) for a, b in pairwise(sent)), default=0.0)


async def test_permit_holds_the_offset_then_the_change_ramps_in(
        tmp_path: Path, invariants: Invariants) -> None:
    bearing = [21.0]  # warm at start: ≈ 17.6 µm with the calibration reference
    sim, rig = await _rig(tmp_path, invariants, bearing)
    await rig.start()
    try:
        await rig.until(lambda: abs(_offset(rig) - 17.6) < 0.5)
        # warm, no checkpoint: the steady state against the calibration reference
        init = [f for _, e, f in rig.log.events if e == "model_initialised"]
        assert init[0]["mode"] == "steady_state" and init[0]["reference"] == "calibration"
        assert _steps(invariants) <= SLEW * 1.0 + 1e-3  # ramped up from 0, no step
        await sim.publish({"plc_update_permitted": 0})  # a cut starts
        await rig.until(lambda: rig.daemon.loop.last_result is not None
                        and rig.daemon.loop.last_result.cause is Cause.WAITING_FOR_PERMISSION)
        held_at = _offset(rig)
        bearing[0] = 21.5  # the machine warms on during the cut
        n = rig.daemon.loop.cycles
        await rig.until(lambda: rig.daemon.loop.cycles >= n + 60)
        r = rig.daemon.loop.last_result
        assert r is not None and r.stage_um == held_at
        assert r.snapshot.pending_um is not None and r.snapshot.pending_um > 5.0
        assert r.model_um is not None and r.model_um > held_at + 5.0
        assert (await sim.outputs())["offset"] == held_at
        status = rig.daemon.telemetry._last_status
        assert "waiting_for_permission" in status and "um pending" in status
        since = len(invariants.log())
        await sim.publish({"plc_update_permitted": 1})  # between cuts
        await rig.until(lambda: rig.daemon.loop.last_result is not None
                        and rig.daemon.loop.last_result.cause is Cause.IN_FORCE
                        and abs(_offset(rig) - (rig.daemon.loop.last_result.model_um or 0)) < 0.2)
        assert _steps(invariants, since) <= SLEW * 1.0 + 1e-3
        names = rig.log.names()
        assert "permission_waiting" in names and "permission_granted" in names
    finally:
        assert await rig.stop() == 0
        await sim.stop()
    assert not invariants.violations


async def test_rezero_by_plc_pulse_and_by_compd_rezero_ramps_and_survives_a_restart(
        tmp_path: Path, invariants: Invariants) -> None:
    bearing = [21.0]
    sim, rig = await _rig(tmp_path, invariants, bearing)
    state_dir = rig.cfg.state_dir
    await rig.start()
    try:
        await rig.until(lambda: abs(_offset(rig) - 17.6) < 0.5)
        since = len(invariants.log())
        await sim.publish({"plc_rezero": 1})  # the M-code's pulse at touch-off
        await rig.until(lambda: rig.daemon.running.cycle is not None
                        and rig.daemon.running.cycle.models.zero_by is not None)
        await sim.publish({"plc_rezero": 0})
        await rig.until(lambda: abs(_offset(rig)) < 0.3)
        assert _steps(invariants, since) <= SLEW * 1.0 + 1e-3
        assert "rezero" in rig.log.names()

        bearing[0] = 21.3  # warms on: the growth since the touch-off, ≈ 5 µm
        await rig.until(lambda: _offset(rig) > 4.0)
        # an operator re-zeroes from the shell: the request goes through the state dir
        done = asyncio.create_task(asyncio.to_thread(
            cli, ["rezero", "--state-dir", str(state_dir), "--wait-s", "60"]))
        await rig.until(lambda: done.done() or "compd rezero" in str(
            rig.daemon.running.cycle.models.zero_by if rig.daemon.running.cycle else ""))
        n = rig.daemon.loop.cycles  # let the checkpoint be read while the clock moves on
        await rig.until(lambda: done.done() or rig.daemon.loop.cycles > n + 200)
        assert await done == 0
        await rig.until(lambda: abs(_offset(rig)) < 0.3)
        saved = json.loads((state_dir / "checkpoint.json").read_text())
        assert "compd rezero" in saved["zero"]["by"]
    finally:
        assert await rig.stop() == 0
    # a restart keeps the re-zero: the prediction stays near zero at the same temperatures
    rig2 = DaemonRig(sim, rig.cfg, invariants, rig.plant, stepped=True)
    await rig2.start()
    try:
        await rig2.until(lambda: rig2.daemon.telemetry.complete_cycles >= 3)
        r = rig2.daemon.loop.last_result
        assert r is not None and r.model_um is not None and abs(r.model_um) < 1.0
        assert r.snapshot.zero_um is not None
    finally:
        assert await rig2.stop() == 0
        await sim.stop()
    assert not invariants.violations


async def test_a_stale_rezero_request_is_refused(tmp_path: Path,
                                                 invariants: Invariants) -> None:
    sim, rig = await _rig(tmp_path, invariants, [21.0])
    state_dir = rig.cfg.state_dir
    state_dir.mkdir(mode=0o700, parents=True, exist_ok=True)
    (state_dir / "rezero.request").write_text(json.dumps(
        {"user": "someone", "id": "abc123", "wall_s": 1.0}))  # left behind long ago
    await rig.start()
    try:
        await rig.until(lambda: rig.daemon.telemetry.complete_cycles >= 5)
        assert rig.daemon.running.cycle is not None
        assert rig.daemon.running.cycle.models.zero_by is None
        refused = [f for _, e, f in rig.log.events if e == "rezero_request_refused"]
        assert refused and "older than" in refused[0]["reason"]
        assert not (state_dir / "rezero.request").exists()
    finally:
        assert await rig.stop() == 0
        await sim.stop()
