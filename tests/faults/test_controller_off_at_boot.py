"""A controller that is off when the shop PC boots (systemd ``Type=notify``).

READY=1 follows the loop's first cycle, not a read that answered (with the
controller off, systemd's start timeout would kill the daemon over and over):
the daemon is up and
retrying, the watchdog is fed, nothing is written, health (the cycle's cause,
the STATUS= line) says why nothing is in force, and compensation starts on the
first cycle the controller answers. Every cycle passes the output invariants;
the daemon runs on the stepped clock against a real simulated Modbus server
that is started only part-way through.
"""

from __future__ import annotations

from pathlib import Path

from compd.core.health import Cause
from drivers.sim.modbus_server import ModbusSimController
from tests.configs import make_config
from tests.faults.daemon_rig import DaemonRig
from tests.faults.invariants import Invariants, invariants
from tests.harness import Notes

__all__ = ["invariants"]  # the autouse fixture, imported to be active here


async def test_ready_while_the_controller_is_off_then_compensates(
        tmp_path: Path, invariants: Invariants) -> None:
    sim = ModbusSimController()  # its port chosen, nobody listening yet: the machine is off
    cfg = make_config(sim, tmp_path, time_scale=1.0, slew_um_s=4.0)
    rig = DaemonRig(sim, cfg, invariants, stepped=True)
    notes = Notes()
    rig.daemon.telemetry.notifier = notes
    await rig.start()
    try:
        await rig.until(lambda: rig.daemon.loop.cycles >= 5)
        off = rig.daemon.loop.last_result
        assert off is not None and off.cause is Cause.CONTROLLER_NOT_ANSWERING
        assert not off.writes.get("offset") and rig.daemon.telemetry.complete_cycles == 0
        assert notes.messages[0].startswith("READY=1"), notes.messages[:3]
        assert notes.messages.count("WATCHDOG=1") >= 5
        assert any(m.startswith("STATUS=") and "controller_not_answering" in m
                   for m in notes.messages)
        ready = [f for _, e, f in rig.log.events if e == "ready"]
        assert ready == [ready[0]] and ready[0]["controller_answers"] is False
        assert ready[0]["cause"] == "controller_not_answering"

        await sim.start()  # the machine is switched on
        await sim.publish({"bearing": 20.0, "ambient": 20.0})
        await rig.until(lambda: rig.daemon.telemetry.complete_cycles >= 3)
        on = rig.daemon.loop.last_result
        assert on is not None and on.cause is Cause.IN_FORCE
        assert sum(m.startswith("READY=1") for m in notes.messages) == 1
    finally:
        assert await rig.stop() == 0
        await sim.stop()
    assert not invariants.violations
