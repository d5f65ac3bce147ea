"""The daemon shell in-process against the real simulated Modbus controller."""

from __future__ import annotations

import asyncio
import contextlib
import socket
from pathlib import Path

import pytest

from compd.config.loader import load_config
from compd.core.output import Status
from compd.runtime.checkpoint import load_checkpoint
from compd.runtime.daemon import Daemon
from compd.runtime.driver_setup import build_driver
from compd.runtime.recorder import read_samples
from compd.runtime.sdnotify import Notifier
from compd.testing import RecordingDriver
from drivers.sim.modbus_server import ModbusSimController
from tests.configs import write_config
from tests.harness import Notes, stepped_daemon
from tests.harness import until as _until
from tests.shipped import LIBRARY


async def test_daemon_compensates_for_a_few_hundred_cycles(
        sim: ModbusSimController, tmp_path: Path) -> None:
    """Hundreds of cycles against the real controller on a stepped clock (nothing
    in this test is about the real clock: the reads and writes are real, the wait
    for the next deadline is not). Time scale 1, so that a request may take the
    0.4 s a loaded machine needs: the clock, not the time scale, sets the pace."""
    cfg = load_config(write_config(tmp_path, sim.endpoint, time_scale=1.0,
                                   checkpoint_every=50))
    driver = RecordingDriver(build_driver(cfg))
    async with stepped_daemon(cfg, driver=driver) as run:
        daemon = run.daemon
        await run.until(lambda: daemon.telemetry.complete_cycles >= 5)
        await sim.publish({"bearing": 22.0})  # +2 K on the bearing: ≈ +32 µm at once
        await run.until(lambda: daemon.loop.cycles >= 300)
        for _ in range(5):  # a controller restart that lost the offset; a forget that
            seen = len(driver.cycles)  # lands between a cycle's read and its write is
            await sim.forget_outputs()  # overwritten unseen: forget until a read saw it
            target = daemon.loop.cycles + 30
            await run.until(lambda t=target: daemon.loop.cycles >= t)
            if any(rb == 0.0 for rb, _ in driver.cycles[seen:]):
                break
        assert await run.stop() == 0

    out = await sim.outputs()
    assert out["heartbeat"] >= 250
    assert int(out["status"]) & Status.OK
    # every offset write is within the limit and moves at most slew·Δt (Δt capped
    # at 2 periods) from what the controller held (read back) in that cycle
    writes = [(rb, w) for rb, w in driver.cycles if w is not None]
    assert len(writes) >= 300
    for rb, w in writes:
        assert abs(w) <= 100.0
        assert rb is not None and abs(w - rb) <= 2 * 1.0 + 1e-3, (rb, w)
    assert max(w for _, w in writes) > 30.0
    # after the controller forgot the offset it was ramped back up, not re-jumped
    forgotten = [i for i, (rb, _) in enumerate(writes) if rb == 0.0 and i > 10]
    assert forgotten and writes[forgotten[0]][1] <= 2.0
    # the checkpoint and the recorder were written
    state = load_checkpoint(cfg.state_dir / "checkpoint.json")
    assert state is not None and state["sequence"] == daemon.loop.cycles
    assert state["offset_um"] == pytest.approx(out["offset"], abs=1e-3)
    assert cfg.recorder_path is not None
    rows = read_samples(cfg.recorder_path)
    assert len(rows["offset_um"]) == daemon.loop.cycles


async def test_dry_run_writes_nothing(sim: ModbusSimController, tmp_path: Path) -> None:
    cfg = load_config(write_config(tmp_path, sim.endpoint, time_scale=1.0))
    async with stepped_daemon(cfg, dry_run=True) as run:
        daemon = run.daemon
        await run.until(lambda: daemon.telemetry.complete_cycles >= 3)
        await sim.publish({"bearing": 21.0})
        after = daemon.telemetry.complete_cycles + 27  # cycles that read the warmer bearing
        await run.until(lambda: daemon.telemetry.complete_cycles >= after)
        assert await run.stop() == 0
    assert daemon.loop.last_result is not None and daemon.loop.last_result.stage_um > 0.0
    assert await sim.outputs() == {"offset": 0.0, "heartbeat": 0.0, "status": 0.0}
    assert not (cfg.state_dir / "checkpoint.json").exists()
    assert not any(r.function_code in (6, 16) for r in sim.requests)


async def test_permanent_rejection_stops_offset_writes_and_raises_alarm(
        sim: ModbusSimController, tmp_path: Path) -> None:
    """On a stepped clock with 0.4 s requests: the two refusals the sim answers must
    reach the daemon as refusals, not as timeouts of a busy machine (8 ms requests)."""
    cfg = load_config(write_config(tmp_path, sim.endpoint, time_scale=1.0))
    async with stepped_daemon(cfg) as run:
        daemon = run.daemon
        await run.until(lambda: daemon.telemetry.complete_cycles >= 3)
        sim.inject_exception("holding", 0, 2, count=2, on="write")  # illegal address
        await run.until(lambda: daemon.running.cycle is not None
                        and daemon.running.cycle.health.write_stopped)
        await run.until(lambda: daemon.loop.cycles >= 20)
        assert await run.stop() == 0
    status = int((await sim.outputs())["status"])
    assert status & Status.WRITE_STOPPED and status & Status.ALARM


async def test_sd_notify_ready_watchdog_status(sim: ModbusSimController,
                                               tmp_path: Path) -> None:
    path = tmp_path / "notify.sock"
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    listener.bind(str(path))
    listener.setblocking(False)
    messages: list[str] = []

    async def receive() -> None:  # as systemd does: the socket's queue holds only
        loop = asyncio.get_running_loop()  # a few datagrams (net.unix.max_dgram_qlen)
        while True:
            messages.append((await loop.sock_recv(listener, 4096)).decode())

    reader = asyncio.create_task(receive())
    try:
        cfg = load_config(write_config(tmp_path, sim.endpoint))
        notifier = Notifier(str(path))
        daemon = Daemon(cfg, notifier=notifier)
        task = asyncio.create_task(daemon.run())
        await _until(lambda: daemon.telemetry.complete_cycles >= 5)
        daemon.request_stop()
        assert await task == 0
        notifier.close()
        reader.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await reader
        while True:
            try:
                messages.append(listener.recv(4096).decode())
            except BlockingIOError:
                break
    finally:
        reader.cancel()
        listener.close()
    assert any(m.startswith("READY=1") for m in messages)
    assert "WATCHDOG=1" in messages
    assert any(m.startswith("STATUS=offset ") and "state ok" in m for m in messages)
    assert messages[-1] == "STOPPING=1"
    ready = next(i for i, m in enumerate(messages) if m.startswith("READY=1"))
    assert "WATCHDOG=1" not in messages[:ready]


async def test_unreachable_controller_holds_and_completes_nothing(tmp_path: Path) -> None:
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    cfg = load_config(write_config(tmp_path, f"modbus://127.0.0.1:{port}"))
    daemon = Daemon(cfg, notifier=Notifier(None))
    task = asyncio.create_task(daemon.run())
    await _until(lambda: daemon.loop.cycles >= 10)
    daemon.request_stop()
    assert await task == 0
    assert daemon.telemetry.complete_cycles == 0
    assert daemon.loop.last_result is not None and daemon.loop.last_result.state == "init"


async def test_second_daemon_on_the_same_state_dir_is_refused(
        sim: ModbusSimController, tmp_path: Path) -> None:
    from compd.runtime.statelock import StateLocked

    cfg = load_config(write_config(tmp_path, sim.endpoint))
    first = Daemon(cfg, notifier=Notifier(None))
    task = asyncio.create_task(first.run())
    await _until(lambda: first.telemetry.complete_cycles >= 2)
    second = Daemon(load_config(cfg.path), notifier=Notifier(None))
    with pytest.raises(StateLocked):
        await second.run()
    first.request_stop()
    assert await task == 0


def _shadow_config(tmp_path: Path, endpoint: str) -> Path:
    """SP2 with a shadow twice its gain; time scale 1 (0.4 s requests)."""
    src = LIBRARY / "sp2.toml"
    (tmp_path / "candidate.toml").write_text(
        src.read_text().replace('name = "SP2 per-spindle"', 'name = "candidate"').replace(
            'a = ["16.0005", "-15.9975", "0"]', 'a = ["32.001", "-31.995", "0"]'))
    return write_config(tmp_path, endpoint, slew_um_s=1000.0,
                        swap=[('file = "sp2"', 'file = "sp2"\nshadow = "candidate.toml"')],
                        time_scale=1.0)


async def test_shadow_model_is_recorded_never_written(sim: ModbusSimController,
                                                      tmp_path: Path) -> None:
    """On a stepped clock with 0.4 s requests: the last cycle's write is compared with
    what the controller holds, and at the sim's default scale (8 ms requests) a busy
    machine could time that one write out."""
    cfg = load_config(_shadow_config(tmp_path, sim.endpoint))
    assert cfg.shadow is not None and cfg.shadow.name == "candidate"
    async with stepped_daemon(cfg) as run:
        daemon = run.daemon
        await run.until(lambda: daemon.telemetry.complete_cycles >= 3)
        await sim.publish({"bearing": 21.0})
        await run.until(lambda: daemon.loop.last_result is not None
                        and (daemon.loop.last_result.model_um or 0.0) > 10.0)
        assert await run.stop() == 0
    r = daemon.loop.last_result
    assert r is not None and r.shadow_um is not None and r.model_um is not None
    assert r.shadow_um == pytest.approx(2 * r.model_um, rel=0.01)
    assert (await sim.outputs())["offset"] == pytest.approx(r.stage_um, abs=1e-3)
    assert r.stage_um == pytest.approx(r.model_um, abs=1e-3)


async def test_sensor_broken_from_the_start_is_up_watched_and_ramps_with_the_alarm(
        sim: ModbusSimController, tmp_path: Path) -> None:
    """An open bearing sensor from the first sample: the daemon is up (READY),
    feeds the watchdog while its loop runs (systemd restarting it would reset
    the hold timer and the offset would be held forever), and ramps to zero with
    the alarm after hold_s (30 machine s). Its cycles paced on a stepped clock."""
    await sim.publish({"bearing": 900.0})
    cfg = load_config(write_config(tmp_path, sim.endpoint, time_scale=1.0))
    notes = Notes()
    async with stepped_daemon(cfg, notifier=notes) as run:
        daemon = run.daemon
        await run.until(lambda: daemon.loop.cycles >= 45)
        assert await run.stop() == 0
    assert daemon.telemetry.complete_cycles == 0
    ready = next(i for i, m in enumerate(notes.messages) if m.startswith("READY=1"))
    assert notes.messages[ready:].count("WATCHDOG=1") >= 40
    assert daemon.loop.last_result is not None and daemon.loop.last_result.state == "ramp"
    status = int((await sim.outputs())["status"])
    assert status & Status.ALARM and status & Status.RAMPING


def test_daemon_has_no_pass_through_properties() -> None:
    # each value has one owner (the loop's counts, the running config and cycle,
    # the journal's log, the sinks' own state): a caller reads it there
    assert [n for n, v in vars(Daemon).items() if isinstance(v, property)] == []
