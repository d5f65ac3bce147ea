"""Controller faults, through the wire against simulated controllers:

- a controller restart that forgets the offset (the sim zeroes its outputs):
  the daemon notices by read-back and ramps back from 0 at the slew limit,
  no jump;
- a write rejected: transient (Modbus exception 6 "busy", FOCAS EW_BUSY, an
  OPC UA BadTypeMismatch after the controller re-typed the offset node) →
  retried the next cycle, compensation goes on when it clears; permanent
  (Modbus 2 / 1, an OPC UA read-only offset node: BadNotWritable or
  BadUserAccessDenied, FOCAS EW_PROT) → alarm, and the offset is never
  written again (checked on the wire where the sim counts requests).

Every cycle also passes the invariants of `invariants.py`. The daemon runs on
a stepped clock (`DaemonRig(stepped=True)`): one machine second between two
samples whatever the load, with real-time I/O limits a busy machine meets.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from compd.core.output import Status
from drivers.sim.modbus_server import ModbusSimController
from drivers.sim.opcua_server import node_id
from drivers.sim.registry import make_sim_controller
from tests.configs import make_config
from tests.faults.daemon_rig import DaemonRig
from tests.faults.invariants import Invariants, invariants

__all__ = ["invariants"]  # the autouse fixture, imported to be active here

SLEW = 4.0
#: the stepped clock counts machine seconds (time_scale 1): a 0.5 s request
#: timeout for the real drivers instead of 8 ms at 50x
SCALE = {"modbus": 1.0, "s7": 1.0, "focas": 1.0, "opcua": 1.0}


async def _rig(protocol: str, tmp_path: Path, inv: Invariants, events: dict[int, Any],
               overrides: dict[str, Any] | None = None) -> tuple[Any, DaemonRig]:
    sim = make_sim_controller(protocol)
    await sim.start()
    await sim.publish({"bearing": 20.0, "ambient": 20.0})
    cfg = make_config(sim, tmp_path, time_scale=SCALE[protocol], slew_um_s=SLEW,
                      overrides=overrides)

    async def plant(index: int, _t: float) -> None:
        await sim.publish({"bearing": 22.0 if index >= 3 else 20.0, "ambient": 20.0})
        if index in events:
            await events[index](sim)

    return sim, DaemonRig(sim, cfg, inv, plant, stepped=True)


@pytest.mark.parametrize("protocol", ["modbus", "s7"])
async def test_restart_forgets_offset_ramps_back(protocol: str, tmp_path: Path,
                                                 invariants: Invariants) -> None:
    forget_at = 30

    async def forget(sim: Any) -> None:
        await sim.forget_outputs()

    sim, rig = await _rig(protocol, tmp_path, invariants, {forget_at: forget})
    try:
        assert await rig.run_until(lambda: rig.daemon.loop.cycles >= forget_at + 14) == 0
        final = (await sim.outputs())["offset"]
    finally:
        await sim.stop()
    log = invariants.log()
    before = log[forget_at - 1].result.stage_um
    assert log[forget_at].readback == 0.0
    first = log[forget_at].written["offset"]
    dt = log[forget_at].now_s - log[forget_at - 1].now_s
    back = next(i for i in range(forget_at, len(log))
                if abs(log[i].result.stage_um - before) <= 0.1) - forget_at
    print(f"{protocol}: offset {before:.3f} µm forgotten; first write {first:.3f} µm "
          f"(R·Δt = {SLEW * dt:.3f}); back within 0.1 µm after {back} cycles")
    assert before > 20.0 and 0.0 < first <= SLEW * min(dt, 2.0) + 1e-3
    assert back + 1 >= before / (2.0 * SLEW)  # ramped (Δt ≤ 2·Ts), not jumped
    assert "readback_mismatch" in rig.log.names()
    assert final == pytest.approx(before, abs=0.01)


async def test_modbus_busy_is_transient_and_retried(tmp_path: Path,
                                                    invariants: Invariants) -> None:
    busy_at, busy_cycles = 8, 5

    async def busy(sim: Any) -> None:
        sim.inject_exception("holding", 0, 6, count=2, on="write")

    async def clear(sim: Any) -> None:
        sim.clear_faults()

    sim, rig = await _rig("modbus", tmp_path, invariants,
                          {busy_at: busy, busy_at + busy_cycles: clear})
    try:
        assert await rig.run_until(lambda: rig.daemon.loop.cycles >= 30) == 0
    finally:
        await sim.stop()
    log = invariants.log()
    failed = [i for i, c in enumerate(log) if c.write_ok is False]
    assert failed == list(range(busy_at, busy_at + busy_cycles))
    # retried: an offset write on every one of those cycles, and the next
    assert all("offset" in log[i].written for i in range(busy_at, busy_at + busy_cycles + 1))
    assert rig.daemon.running.cycle is not None
    assert not rig.daemon.running.cycle.health.write_stopped
    assert log[busy_at + busy_cycles].write_ok is True
    assert int((await sim.outputs())["status"]) & Status.OK
    assert log[-1].result.stage_um > 30.0
    print(f"modbus busy: {len(failed)} cycles refused, retried each next cycle, "
          f"offset {log[-1].result.stage_um:.3f} µm at the end")


def _touches_offset(sim: ModbusSimController, start: int) -> int:
    """Write requests (FC 6/16) since `start` touching the offset's registers 0..1."""
    return sum(1 for r in sim.requests[start:]
               if r.function_code in (6, 16) and r.address < 2 and r.address + r.count > 0)


@pytest.mark.parametrize("code", [2, 1])
async def test_modbus_permanent_refusal_stops_offset_writes(
        code: int, tmp_path: Path, invariants: Invariants) -> None:
    refuse_at = 10
    mark: dict[str, int] = {}

    async def refuse(sim: Any) -> None:
        sim.inject_exception("holding", 0, code, count=2, on="write")

    sim, rig = await _rig("modbus", tmp_path, invariants, {refuse_at: refuse})
    try:
        await rig.start()
        await rig.until(lambda: rig.daemon.running.cycle is not None
                        and rig.daemon.running.cycle.health.write_stopped)
        mark["requests"] = len(sim.requests)
        n = rig.daemon.loop.cycles
        await rig.until(lambda: rig.daemon.loop.cycles >= n + 20)
        assert await rig.stop() == 0
        status = int((await sim.outputs())["status"])
        after = _touches_offset(sim, mark["requests"])
    finally:
        await sim.stop()
    log = invariants.log()
    stopped = next(i for i, c in enumerate(log) if c.write_ok is False)
    assert stopped == refuse_at
    assert all("offset" not in c.written for c in log[stopped + 1:])
    assert after == 0, "no offset write reached the controller after the refusal"
    assert status & Status.ALARM and status & Status.WRITE_STOPPED
    assert "offset_write_stopped" in rig.log.names()
    print(f"modbus code {code}: permanent at cycle {stopped}, 0 offset writes after, "
          f"{len(log) - stopped - 1} cycles with heartbeat/status only, status {status:#x}")


async def test_opcua_read_only_offset_node_is_permanent(tmp_path: Path,
                                                        invariants: Invariants) -> None:
    """The offset configured on a node the server does not let clients write
    (BadNotWritable / BadUserAccessDenied)."""
    sim = make_sim_controller("opcua")
    await sim.start()
    try:
        await sim.publish({"bearing": 20.0, "ambient": 20.0})
        cfg = make_config(sim, tmp_path, time_scale=SCALE["opcua"], slew_um_s=SLEW,
                          overrides={"output": {"offset": {"node": node_id("table")}}})

        async def plant(index: int, _t: float) -> None:
            await sim.publish({"bearing": 22.0 if index >= 3 else 20.0, "ambient": 20.0})

        rig = DaemonRig(sim, cfg, invariants, plant, stepped=True)
        await rig.start()
        await rig.until(lambda: rig.daemon.running.cycle is not None
                        and rig.daemon.running.cycle.health.write_stopped)
        writes = sim.write_requests  # type: ignore[attr-defined]
        n = rig.daemon.loop.cycles
        await rig.until(lambda: rig.daemon.loop.cycles >= n + 10)
        assert await rig.stop() == 0
        table = await sim.value("table")  # type: ignore[attr-defined]
        status = int((await sim.outputs())["status"])
        writes_after = sim.write_requests - writes  # type: ignore[attr-defined]
    finally:
        await sim.stop()
    log = invariants.log()
    stopped = next(i for i, c in enumerate(log) if c.write_ok is False)
    assert all("offset" not in c.written for c in log[stopped + 1:])
    assert table == 0.0  # never written
    assert status & Status.WRITE_STOPPED and status & Status.ALARM
    reason = next(f for _, e, f in rig.log.events if e == "offset_write_stopped")["reason"]
    assert "BadNotWritable" in reason or "BadUserAccessDenied" in reason, reason
    print(f"opcua read-only offset: stopped at cycle {stopped} ({reason}); "
          f"{writes_after} Write requests after (heartbeat/status only)")


async def test_focas_ew_prot_is_permanent(tmp_path: Path, invariants: Invariants) -> None:
    """The offset configured in the F area (CNC → PMC signals): the CNC answers
    pmc_wrpmcrng with EW_PROT, a permanent refusal."""
    sim = make_sim_controller("focas")
    await sim.start()
    try:
        await sim.publish({"bearing": 20.0, "ambient": 20.0})
        cfg = make_config(sim, tmp_path, time_scale=SCALE["focas"], slew_um_s=SLEW,
                          overrides={"output": {"offset": {"area": "F", "address": 100}}})

        async def plant(index: int, _t: float) -> None:
            await sim.publish({"bearing": 22.0 if index >= 3 else 20.0, "ambient": 20.0})

        rig = DaemonRig(sim, cfg, invariants, plant, stepped=True)
        await rig.start()
        await rig.until(lambda: rig.daemon.running.cycle is not None
                        and rig.daemon.running.cycle.health.write_stopped)
        n = rig.daemon.loop.cycles
        await rig.until(lambda: rig.daemon.loop.cycles >= n + 10)
        assert await rig.stop() == 0
        status = int((await sim.outputs())["status"])
    finally:
        await sim.stop()
        sim.close()  # type: ignore[attr-defined]
    log = invariants.log()
    stopped = next(i for i, c in enumerate(log) if c.write_ok is False)
    assert all("offset" not in c.written for c in log[stopped + 1:])
    reason = next(f for _, e, f in rig.log.events if e == "offset_write_stopped")["reason"]
    assert "EW_PROT" in reason, reason
    assert status & Status.WRITE_STOPPED and status & Status.ALARM
    print(f"focas EW_PROT: stopped at cycle {stopped} ({reason})")


async def test_focas_ew_busy_is_transient_and_retried(tmp_path: Path,
                                                      invariants: Invariants) -> None:
    """The CNC answers pmc_wrpmcrng with EW_BUSY (-1) three times: each of
    those cycles fails, the next cycle writes again, and compensation goes on
    (never stopped, no alarm)."""
    busy_at, busy_writes = 8, 3

    async def busy(sim: Any) -> None:
        sim.inject_busy_writes(busy_writes)

    sim, rig = await _rig("focas", tmp_path, invariants, {busy_at: busy})
    try:
        assert await rig.run_until(lambda: rig.daemon.loop.cycles >= 30) == 0
        left = sim.busy_writes
        status = int((await sim.outputs())["status"])
        written = (await sim.outputs())["offset"]
    finally:
        await sim.stop()
        sim.close()
    log = invariants.log()
    failed = [i for i, c in enumerate(log) if c.write_ok is False]
    # one combined pmc_wrpmcrng (offset, heartbeat, status) per cycle: one EW_BUSY each
    assert failed == list(range(busy_at, busy_at + busy_writes)), failed
    assert left == 0
    assert all("offset" in log[i].written for i in range(busy_at, busy_at + busy_writes + 1))
    assert log[busy_at + busy_writes].write_ok is True
    reasons = [f.get("reason", "") for _, e, f in rig.log.events if e == "write_failed"]
    assert reasons and all("EW_BUSY" in r for r in reasons), reasons
    assert rig.daemon.running.cycle is not None
    assert not rig.daemon.running.cycle.health.write_stopped
    assert "offset_write_stopped" not in rig.log.names()
    assert status & Status.OK and not status & Status.ALARM
    assert log[-1].result.stage_um > 30.0
    assert written == pytest.approx(log[-1].result.stage_um, abs=0.1)  # ×0.1 µm long
    print(f"focas EW_BUSY: {len(failed)} cycles refused, retried each next cycle, "
          f"offset {log[-1].result.stage_um:.3f} µm at the end")


@pytest.mark.parametrize(("access", "code"), [
    ({"writable": False}, "BadNotWritable"),
    ({"user_writable": False}, "BadUserAccessDenied")])
async def test_opcua_offset_made_read_only_is_permanent(
        access: dict[str, bool], code: str, tmp_path: Path, invariants: Invariants) -> None:
    """The controller takes CurrentWrite out of the offset node's AccessLevel
    (BadNotWritable) or UserAccessLevel (BadUserAccessDenied) while the daemon
    runs: alarm, offset writing stopped; heartbeat and status still written."""
    refuse_at = 10

    async def refuse(sim: Any) -> None:
        await sim.set_write_access("offset", **access)

    sim, rig = await _rig("opcua", tmp_path, invariants, {refuse_at: refuse})
    try:
        await rig.start()
        await rig.until(lambda: rig.daemon.running.cycle is not None
                        and rig.daemon.running.cycle.health.write_stopped)
        held = await sim.value("offset")
        n = rig.daemon.loop.cycles
        await rig.until(lambda: rig.daemon.loop.cycles >= n + 10)
        assert await rig.stop() == 0
        outputs = await sim.outputs()
    finally:
        await sim.stop()
    log = invariants.log()
    stopped = next(i for i, c in enumerate(log) if c.write_ok is False)
    assert stopped == refuse_at
    assert all("offset" not in c.written for c in log[stopped + 1:])
    assert outputs["offset"] == held
    assert int(outputs["heartbeat"]) == log[-1].result.heartbeat
    status = int(outputs["status"])
    assert status & Status.WRITE_STOPPED and status & Status.ALARM
    reason = next(f for _, e, f in rig.log.events if e == "offset_write_stopped")["reason"]
    assert code in reason, reason
    print(f"opcua {code}: permanent at cycle {stopped} ({reason})")


async def test_opcua_offset_node_retyped_is_transient(tmp_path: Path,
                                                      invariants: Invariants) -> None:
    """The controller deletes the offset node and adds it again as Double (our
    type cache says Float): the Write gets BadTypeMismatch, the driver re-reads
    the DataType, the cycle is a transient failure and the next one writes a
    Double; the daemon ramps back from the re-created node's 0, never stops."""
    retype_at = 10

    async def retype(sim: Any) -> None:
        from asyncua import ua
        await sim.retype("offset", ua.VariantType.Double)

    sim, rig = await _rig("opcua", tmp_path, invariants, {retype_at: retype})
    try:
        assert await rig.run_until(lambda: rig.daemon.loop.cycles >= retype_at + 30) == 0
        written = await sim.value("offset")
    finally:
        await sim.stop()
    log = invariants.log()
    # the first write of the offset after the retype is refused; on a busy machine the
    # read right after the retype may time out first (that cycle writes the heartbeat
    # and status, not the offset), so it is the first cycle that wrote the offset
    first = next(i for i in range(retype_at, len(log)) if "offset" in log[i].written)
    failed = [i for i, c in enumerate(log) if c.write_ok is False]
    assert failed == [first] and first - retype_at <= 3, (retype_at, failed)
    assert log[first + 1].write_ok is True and "offset" in log[first + 1].written
    reasons = [f.get("reason", "") for _, e, f in rig.log.events if e == "write_failed"]
    assert len(reasons) == 1 and "BadTypeMismatch" in reasons[0] \
        and "Double" in reasons[0], reasons
    assert rig.daemon.running.cycle is not None
    assert not rig.daemon.running.cycle.health.write_stopped
    assert "offset_write_stopped" not in rig.log.names()
    assert written == pytest.approx(log[-1].result.stage_um, abs=1e-3)
    assert log[-1].result.stage_um > 30.0
    print(f"opcua retyped offset node: 1 cycle refused ({reasons[0]}), "
          f"offset {written:.3f} µm at the end")
