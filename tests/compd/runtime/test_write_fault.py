"""Offset writes that keep failing: a write fault with its
status bit and state, and a recorder that keeps what the controller confirmed
apart from what was sent."""

from __future__ import annotations

import sqlite3
from pathlib import Path

from compd.config.loader import load_config
from compd.core.cycle import WRITE_FAULT_AFTER, Cycle, Outcome
from compd.core.output import Status
from compd.testing import FakeClock
from drivers.sim.modbus_server import ModbusSimController
from tests.compd.core.cycle_helpers import params, run_warm, samples, sp2
from tests.configs import write_config
from tests.harness import stepped_daemon


def test_repeated_write_failures_are_a_fault_until_a_write_succeeds() -> None:
    cycle, clock = Cycle(params(), sp2()), FakeClock()
    run_warm(cycle, clock, 5, bearing=20.0)
    faults = []
    for i in range(WRITE_FAULT_AFTER + 2):
        t = clock.tick()
        plan = cycle.plan(t, samples(t, 20.5))
        assert plan.sent_um == plan.stage_um
        r = cycle.commit(Outcome.failed("offset", permanent=False, reason="out of range"))
        ev = r.write_events
        # not confirmed: the row keeps it as attempted only
        assert r.record.offset_um is None and r.record.attempted_um is not None
        faults += [i for e in ev if e.name == "write_fault"]
    assert faults == [WRITE_FAULT_AFTER - 1]  # once, at the WRITE_FAULT_AFTER-th
    assert r.status & Status.WRITE_FAULT and r.status & Status.ALARM
    assert not r.status & Status.OK and r.state == "write_fault"
    t = clock.tick()
    cycle.plan(t, samples(t, 20.5))
    r = cycle.commit()
    assert r.record.offset_um == r.record.attempted_um == r.stage_um
    t = clock.tick()
    plan = cycle.plan(t, samples(t, 20.5))
    assert "write_recovered" in [e.name for e in plan.events]
    assert plan.status & Status.OK and not plan.status & Status.ALARM and plan.state == "ok"


def test_a_few_failures_are_no_fault() -> None:
    cycle, clock = Cycle(params(), sp2()), FakeClock()
    run_warm(cycle, clock, 5, bearing=20.0)
    for _ in range(WRITE_FAULT_AFTER - 1):
        t = clock.tick()
        cycle.plan(t, samples(t, 20.5))
        cycle.commit(Outcome.failed("offset", permanent=False, reason="busy"))
    run_warm(cycle, clock, 1, bearing=20.5)
    for _ in range(WRITE_FAULT_AFTER - 1):
        t = clock.tick()
        r = cycle.plan(t, samples(t, 20.5))
        cycle.commit(Outcome.failed("offset", permanent=False, reason="busy"))
    assert not cycle.health.write_fault and r.status & Status.OK


async def test_daemon_records_only_confirmed_offsets_and_reports_the_write_fault(
        sim: ModbusSimController, tmp_path: Path) -> None:
    """On a stepped clock (time scale 1: a 0.4 s request timeout), paced as fast as the
    daemon sleeps: the only write failures are the controller's refusals, not timeouts
    of a busy machine (at the sim's default scale a request has 8 ms)."""
    cfg = load_config(write_config(tmp_path, sim.endpoint, time_scale=1.0))
    async with stepped_daemon(cfg) as run:
        daemon = run.daemon
        await run.until(lambda: daemon.telemetry.complete_cycles >= 3)
        await sim.publish({"bearing": 22.0})
        sim.inject_exception("holding", 0, 6, count=4, on="write")  # busy, for a while
        await run.until(lambda: daemon.running.cycle is not None
                        and daemon.running.cycle.health.write_fault)
        await run.until(lambda: daemon.loop.last_result is not None
                        and daemon.loop.last_result.state == "write_fault")
        assert daemon.loop.last_result is not None
        assert daemon.loop.last_result.status & Status.WRITE_FAULT
        assert daemon.metrics.fault_state._value.get() == 3  # the gauge
        sim.clear_faults()
        await run.until(lambda: daemon.running.cycle is not None
                        and not daemon.running.cycle.health.write_fault)
        n = daemon.loop.cycles
        await run.until(lambda: daemon.loop.cycles >= n + 3)
        assert await run.stop() == 0
    assert cfg.recorder_path is not None
    with sqlite3.connect(cfg.recorder_path) as db:
        rows = db.execute("SELECT offset_um, attempted_um, state FROM samples").fetchall()
    failed = [r for r in rows if r[1] is not None and r[0] is None]
    confirmed = [r for r in rows if r[0] is not None]
    assert len(failed) >= WRITE_FAULT_AFTER
    assert any(r[2] == "write_fault" for r in failed)
    # a confirmed offset is exactly what was sent; no row claims an unsent offset
    assert confirmed and all(r[0] == r[1] for r in confirmed)
    # after the fault, confirmed offsets again (the run's very last cycle may itself time
    # out on a busy machine: recovery is shown by the rows after the fault, not the last)
    last_fault = max(i for i, r in enumerate(rows) if r[2] == "write_fault")
    assert any(r[0] is not None and r[2] == "ok" for r in rows[last_fault + 1:]), \
        rows[last_fault:]
