"""SIGHUP reload of `compd run` (a real process, real signals, real time) against
the simulated Modbus controller: a valid new config (another model, another
slew) is swapped in and hands over under the slew limit; a broken one is
refused with the key while the old config keeps running; a storm of HUPs is
served, every one.

These assert only what a loaded machine cannot change (the swap, the slew
bound, the exit status), never a count of missed deadlines: that a reload
never costs a cycle is tested deterministically, in lockstep, in
test_reload_lockstep.py."""

from __future__ import annotations

import asyncio
import itertools
import json
import signal
from pathlib import Path
from typing import Any

from tests.configs import write_config
from tests.faults.daemon_run import RecordingSim, start_daemon
from tests.harness import until, until_output

SLEW_UM_S = 1.0


def _events(log: Path, name: str) -> list[dict[str, Any]]:  # the log's JSON lines
    out = []
    for line in log.read_text().splitlines():
        if f'"{name}"' in line:
            out.append(json.loads(line[line.index("{"):]))
    return out


async def _until_logged(log: Path, name: str, proc: asyncio.subprocess.Process,
                        count: int = 1, limit_s: float = 120.0) -> None:
    """Until the daemon logged `name` `count` times: polled on a condition, bounded
    only by a generous limit (a loaded machine makes this slower, never red)."""
    async def logged() -> bool:
        return len(await asyncio.to_thread(_events, log, name)) >= count

    await until(logged, proc, log, f"{name} logged {count} time(s)", limit_s=limit_s,
                every_s=0.01)


async def _stop(proc: asyncio.subprocess.Process) -> int:
    proc.send_signal(signal.SIGTERM)
    return await asyncio.wait_for(proc.wait(), 20.0)


async def test_hup_swaps_in_another_model_under_the_slew_limit(
        rec: RecordingSim, tmp_path: Path) -> None:
    # a 100 ms real period and a 50 ms request timeout: a loaded machine's late
    # answers are not read failures (which would hold the offset)
    config = write_config(tmp_path, rec.sim.endpoint, slew_um_s=SLEW_UM_S, time_scale=10.0,
                          timeout_s=0.05)
    log = tmp_path / "daemon.log"
    proc = await start_daemon(config, log)
    try:
        await until_output(rec.sim, "heartbeat", lambda v: v >= 3, proc, log)
        await rec.sim.publish({"bearing": 22.5})  # sp2 wants ≈ +40 µm
        await until_output(rec.sim, "offset", lambda v: v >= 4.0, proc, log)
        # another model: sp3 (same channels), and a slower slew limit
        config.write_text(config.read_text().replace('file = "sp2"', 'file = "sp3"')
                          .replace(f"slew_um_s = {SLEW_UM_S}", "slew_um_s = 0.5"))
        proc.send_signal(signal.SIGHUP)
        await _until_logged(log, "reload_succeeded", proc)
        swapped = len(rec.offsets)  # every write from here on is the new config's
        beat = (await rec.sim.outputs())["heartbeat"]
        await until_output(rec.sim, "heartbeat", lambda v: v >= beat + 6, proc, log)
        assert await _stop(proc) == 0
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
    (done,) = _events(log, "reload_succeeded")
    assert "model" in done["restarted"] and done["filters"] == "restart_at_steady_state"
    assert {"model.file", "output.slew_um_s"} <= set(done["changed"])
    assert "controller" not in done["restarted"]  # same endpoint and addresses: same link
    # never a jump: every step within the (old, then new) slew limit
    steps = [abs(b - a) for a, b in itertools.pairwise(rec.offsets)]
    assert max(steps) <= 2 * SLEW_UM_S * 1.0 + 1e-3
    after = [abs(b - a) for a, b in itertools.pairwise(rec.offsets[swapped + 1:])]
    assert after and max(after) <= 2 * 0.5 + 1e-3
    (stopped,) = _events(log, "daemon_stopped")
    assert stopped["reloads"] == 1


async def test_hup_with_a_broken_config_keeps_the_old_one(
        rec: RecordingSim, tmp_path: Path) -> None:
    config = write_config(tmp_path, rec.sim.endpoint)
    good = config.read_text()
    log = tmp_path / "daemon.log"
    proc = await start_daemon(config, log)
    try:
        await until_output(rec.sim, "heartbeat", lambda v: v >= 3, proc, log)
        config.write_text(good.replace("limit_um = 100.0", "limit_um = 0"))
        proc.send_signal(signal.SIGHUP)
        await _until_logged(log, "reload_failed", proc)
        beat = (await rec.sim.outputs())["heartbeat"]
        await until_output(rec.sim, "heartbeat", lambda v: v >= beat + 5, proc, log)
        # a change that needs a restart is refused the same way
        config.write_text(good.replace("time_scale = 50.0", "time_scale = 40.0"))
        proc.send_signal(signal.SIGHUP)
        await _until_logged(log, "reload_failed", proc, count=2)
        assert proc.returncode is None
        assert await _stop(proc) == 0
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
    failed = _events(log, "reload_failed")
    assert [f["key"] for f in failed] == ["output.limit_um", "machine.time_scale"]
    assert failed[0]["level"] == "error" and failed[0]["reason"]
    assert not _events(log, "reload_succeeded")
    (stopped,) = _events(log, "daemon_stopped")
    assert stopped["reloads"] == 0


async def test_hup_storm_during_cycles_misses_no_cycle(
        rec: RecordingSim, tmp_path: Path) -> None:
    """HUPs sent at random points of the cycle (mid-read, mid-write): every one
    is served and the unchanged model carries its filters over (the cycles
    kept are checked in lockstep: test_reload_lockstep.py)."""
    config = write_config(tmp_path, rec.sim.endpoint)
    log = tmp_path / "daemon.log"
    proc = await start_daemon(config, log)
    try:
        await until_output(rec.sim, "heartbeat", lambda v: v >= 3, proc, log)
        for i in range(10):
            # a harmless change each time (checkpoint cadence): a real swap every time
            text = config.read_text()
            config.write_text(text.replace(f"checkpoint_every = {20 + i}",
                                           f"checkpoint_every = {21 + i}"))
            proc.send_signal(signal.SIGHUP)
            await asyncio.sleep(0.013 * (i + 1))  # fractions of the 20 ms real period
            await _until_logged(log, "reload_succeeded", proc, count=i + 1)
        assert await _stop(proc) == 0
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
    done = _events(log, "reload_succeeded")
    assert len(done) == 10
    assert all(d["filters"] == "carried_over" and d["restarted"] == []
               and d["changed"] == ["state.checkpoint_every"] for d in done)
    (stopped,) = _events(log, "daemon_stopped")
    assert stopped["reloads"] == 10


async def test_hup_with_another_endpoint_reconnects(
        rec: RecordingSim, tmp_path: Path) -> None:
    """The controller's endpoint changes (a replaced PLC): the new link is made
    before the swap, the writes go to it, and the old link is closed."""
    from drivers.sim.modbus_server import ModbusSimController

    other = ModbusSimController()
    await other.start()
    await other.publish({"bearing": 20.0, "ambient": 20.0})
    config = write_config(tmp_path, rec.sim.endpoint)
    log = tmp_path / "daemon.log"
    proc = await start_daemon(config, log)
    try:
        await until_output(rec.sim, "heartbeat", lambda v: v >= 3, proc, log)
        config.write_text(config.read_text().replace(rec.sim.endpoint, other.endpoint))
        proc.send_signal(signal.SIGHUP)
        await until_output(other, "heartbeat", lambda v: v >= 5, proc, log)
        beat = (await rec.sim.outputs())["heartbeat"]
        # ten more cycles, counted by the new controller: the old one hears none of them
        new_beat = (await other.outputs())["heartbeat"]
        await until_output(other, "heartbeat", lambda v: v >= new_beat + 10, proc, log)
        assert (await rec.sim.outputs())["heartbeat"] == beat
        assert await _stop(proc) == 0
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
        await other.stop()
    (done,) = _events(log, "reload_succeeded")
    assert "controller" in done["restarted"] and "model" not in done["restarted"]
    assert any(e["endpoint"] == other.endpoint for e in _events(log, "controller_connected"))
