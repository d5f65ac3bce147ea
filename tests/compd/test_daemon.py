"""The daemon shell in-process against the real simulated Modbus controller."""

from __future__ import annotations

import asyncio
import socket
from pathlib import Path

import pytest

from compd.checkpoint import load_checkpoint
from compd.config import load_config
from compd.daemon import Daemon
from compd.driver_setup import build_driver
from compd.output import Status
from compd.recorder import read_samples
from compd.sdnotify import Notifier
from drivers.sim.modbus_server import ModbusSimController

from .daemon_helpers import RecordingDriver, write_config


@pytest.fixture
async def sim() -> ModbusSimController:
    controller = ModbusSimController()
    await controller.start()
    await controller.publish({"bearing": 20.0, "ambient": 20.0})
    try:
        yield controller  # type: ignore[misc]
    finally:
        await controller.stop()


async def _until(predicate: object, limit: int = 2000) -> None:
    for _ in range(limit):
        if predicate():  # type: ignore[operator]
            return
        await asyncio.sleep(0.005)
    raise AssertionError("condition not reached")


async def test_daemon_compensates_for_a_few_hundred_cycles(
        sim: ModbusSimController, tmp_path: Path) -> None:
    cfg = load_config(write_config(tmp_path, sim.endpoint, checkpoint_every=50))
    driver = RecordingDriver(build_driver(cfg))
    daemon = Daemon(cfg, driver=driver, notifier=Notifier(None))
    task = asyncio.create_task(daemon.run())
    await _until(lambda: daemon.complete_cycles >= 5)
    await sim.publish({"bearing": 22.0})  # +2 K on the bearing: ≈ +32 µm at once
    await _until(lambda: daemon.cycles >= 300)
    await sim.forget_outputs()  # a controller restart that lost the offset
    await _until(lambda: daemon.cycles >= 330)
    daemon.request_stop()
    assert await task == 0

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
    assert forgotten and writes[forgotten[0]][1] <= 2.0  # type: ignore[operator]
    # the checkpoint and the recorder were written
    state = load_checkpoint(cfg.state_dir / "checkpoint.json")
    assert state is not None and state["sequence"] == daemon.cycles
    assert state["offset_um"] == pytest.approx(out["offset"], abs=1e-3)
    assert cfg.recorder_path is not None
    rows = read_samples(cfg.recorder_path)
    assert len(rows["offset_um"]) == daemon.cycles


async def test_dry_run_writes_nothing(sim: ModbusSimController, tmp_path: Path) -> None:
    cfg = load_config(write_config(tmp_path, sim.endpoint))
    daemon = Daemon(cfg, dry_run=True, notifier=Notifier(None))
    task = asyncio.create_task(daemon.run())
    await _until(lambda: daemon.complete_cycles >= 3)
    await sim.publish({"bearing": 21.0})
    await _until(lambda: daemon.complete_cycles >= 30)
    daemon.request_stop()
    assert await task == 0
    assert daemon.last_result is not None and daemon.last_result.offset_um > 0.0
    assert await sim.outputs() == {"offset": 0.0, "heartbeat": 0.0, "status": 0.0}
    assert not (cfg.state_dir / "checkpoint.json").exists()
    assert not any(r.function_code in (6, 16) for r in sim.requests)


async def test_permanent_rejection_stops_offset_writes_and_raises_alarm(
        sim: ModbusSimController, tmp_path: Path) -> None:
    cfg = load_config(write_config(tmp_path, sim.endpoint))
    daemon = Daemon(cfg, notifier=Notifier(None))
    task = asyncio.create_task(daemon.run())
    await _until(lambda: daemon.complete_cycles >= 3)
    sim.inject_exception("holding", 0, 2, count=2, on="write")  # illegal address
    await _until(lambda: daemon.cycle is not None and daemon.cycle.write_stopped)
    await _until(lambda: daemon.cycles >= 20)
    daemon.request_stop()
    assert await task == 0
    status = int((await sim.outputs())["status"])
    assert status & Status.WRITE_STOPPED and status & Status.ALARM


async def test_sd_notify_ready_watchdog_status(sim: ModbusSimController,
                                               tmp_path: Path) -> None:
    path = tmp_path / "notify.sock"
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    listener.bind(str(path))
    listener.setblocking(False)
    try:
        cfg = load_config(write_config(tmp_path, sim.endpoint))
        notifier = Notifier(str(path))
        daemon = Daemon(cfg, notifier=notifier)
        task = asyncio.create_task(daemon.run())
        await _until(lambda: daemon.complete_cycles >= 5)
        daemon.request_stop()
        assert await task == 0
        notifier.close()
        messages = []
        while True:
            try:
                messages.append(listener.recv(4096).decode())
            except BlockingIOError:
                break
    finally:
        listener.close()
    assert any(m.startswith("READY=1") for m in messages)
    assert "WATCHDOG=1" in messages
    assert any(m.startswith("STATUS=offset ") and "state ok" in m for m in messages)
    assert messages[-1] == "STOPPING=1"
    ready = next(i for i, m in enumerate(messages) if m.startswith("READY=1"))
    assert "WATCHDOG=1" not in messages[:ready]


async def test_unreachable_controller_holds_and_never_signals_ready(tmp_path: Path) -> None:
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    cfg = load_config(write_config(tmp_path, f"modbus://127.0.0.1:{port}"))
    daemon = Daemon(cfg, notifier=Notifier(None))
    task = asyncio.create_task(daemon.run())
    await _until(lambda: daemon.cycles >= 10)
    daemon.request_stop()
    assert await task == 0
    assert daemon.complete_cycles == 0
    assert daemon.last_result is not None and daemon.last_result.state == "init"
