"""No exception in the cycle ends the daemon without its fault or shutdown policy
(an OverflowError in the estimator at a probe or in a reload's handover must not end
`compd run` with exit 1, the offset frozen, no checkpoint). In-process against the
real simulated Modbus controller."""

from __future__ import annotations

import asyncio
import itertools
from collections.abc import Mapping, MutableMapping, Sequence
from pathlib import Path
from typing import Any

import pytest
import structlog

from compd.config.loader import LoadedConfig, load_config
from compd.core.cycle import Cycle
from compd.core.output import Status
from compd.runtime.checkpoint import load_checkpoint
from compd.runtime.driver_setup import build_driver
from compd.sysexits import EX_SOFTWARE
from compd.testing import RecordingDriver
from drivers.base import Sample
from drivers.sim.modbus_server import ModbusSimController
from tests.configs import write_config
from tests.harness import Paced, stepped_daemon, until

ADAPTATION = """
[adaptation]
enabled = true
mode = "apply"
probe_value = { kind = "input", address = 12, type = "float32" }
probe_counter = { kind = "input", address = 14, type = "uint16" }
max_total_um = 20.0
"""


def _named(logs: Sequence[Mapping[str, Any]], name: str) -> list[Mapping[str, Any]]:
    return [e for e in logs if e["event"] == name]


async def _warm(sim: ModbusSimController, run: Paced) -> Cycle:
    daemon = run.daemon
    await run.until(lambda: daemon.telemetry.complete_cycles >= 3)
    await sim.publish({"bearing": 21.5})  # sp2 wants ≈ +25 µm
    await run.until(lambda: daemon.loop.last_result is not None
                    and daemon.loop.last_result.stage_um > 15.0)
    assert daemon.running.cycle is not None
    return daemon.running.cycle


async def test_a_model_step_that_raises_every_cycle_is_held_then_ramped(
        sim: ModbusSimController, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The cycle raises on every complete sample (as the estimator's OverflowError did
    at each probe): each cycle is stepped again as a failed read, so the fault policy
    holds (hold_s), then ramps to 0 at the slew limit with the alarm; one log line.
    On a stepped clock (time scale 1, a 0.4 s request timeout), paced as fast as the
    daemon sleeps: the hold and the ramp are counted in cycles, not waited out."""
    cfg = load_config(write_config(tmp_path, sim.endpoint, time_scale=1.0))
    driver = RecordingDriver(build_driver(cfg))
    with structlog.testing.capture_logs() as logs:
        async with stepped_daemon(cfg, driver=driver) as run:
            daemon = run.daemon
            cycle = await _warm(sim, run)

            def overflow(*_: object, **__: object) -> float:
                raise OverflowError("(34, 'Numerical result out of range')")

            monkeypatch.setattr(cycle.models, "step", overflow)
            at = len(driver.cycles)
            await run.until(lambda: daemon.loop.last_result is not None
                            and daemon.loop.last_result.stage_um == 0.0)
            assert not run.task.done()  # still cycling: heartbeat and status go on
            beat = (await sim.outputs())["heartbeat"]
            status = int((await sim.outputs())["status"])
            assert await run.stop() == 0
    errors = _named(logs, "cycle_error")
    assert len(errors) == 1 and errors[0]["stage"] == "step"
    assert "OverflowError" in errors[0]["error"] and errors[0]["log_level"] == "error"
    assert _named(logs, "fault_ramp_to_zero")
    assert status & Status.ALARM
    assert beat > 0
    # held, then ramped at the slew limit (1 µm/s, Δt capped at 2 periods): never a jump
    writes = [w for _, w in driver.cycles[at:] if w is not None]
    assert writes[-1] == 0.0 and max(writes) > 15.0
    assert max(abs(b - a) for a, b in itertools.pairwise(writes)) <= 2 * 1.0 + 1e-3
    state = load_checkpoint(cfg.state_dir / "checkpoint.json")
    assert state is not None and state["offset_um"] == 0.0


async def test_a_cycle_that_raises_even_as_a_failed_read_ends_with_its_checkpoint(
        sim: ModbusSimController, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Nothing left to step: logged (cycle_broken, with the exception), the shutdown
    policy ("hold": the offset stays), a checkpoint, exit 70 (systemd restarts).
    On a stepped clock with 0.4 s requests: the offset the checkpoint holds is the one
    the controller confirmed, which a write timed out on a busy machine is not."""
    cfg = load_config(write_config(tmp_path, sim.endpoint, checkpoint_every=100000,
                                   time_scale=1.0))
    with structlog.testing.capture_logs() as logs:
        async with stepped_daemon(cfg) as run:
            cycle = await _warm(sim, run)
            sequence = cycle.sequence

            def broken(*_: object, **__: object) -> object:
                raise ValueError("math domain error")

            monkeypatch.setattr(cycle.health, "decide", broken)
            assert await asyncio.wait_for(run.task, 30.0) == EX_SOFTWARE
    (line,) = _named(logs, "cycle_broken")
    assert "ValueError: math domain error" in line["error"] and line["exc_info"]
    (stopped,) = _named(logs, "daemon_stopped")
    assert stopped["broken"] is True
    state = load_checkpoint(cfg.state_dir / "checkpoint.json")
    assert state is not None and state["sequence"] >= sequence  # written at the end
    assert state["offset_um"] == pytest.approx((await sim.outputs())["offset"], abs=1e-3)


async def test_a_sink_that_raises_never_stops_the_cycle(
        sim: ModbusSimController, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    cfg = load_config(write_config(tmp_path, sim.endpoint, time_scale=1.0))
    with structlog.testing.capture_logs() as logs:
        async with stepped_daemon(cfg) as run:
            daemon = run.daemon
            await run.until(lambda: daemon.telemetry.complete_cycles >= 3)

            def full(*_: object) -> None:
                raise RuntimeError("recorder exploded")

            monkeypatch.setattr(daemon.recorder, "feed", full)
            done = daemon.telemetry.complete_cycles
            await run.until(lambda: daemon.telemetry.complete_cycles >= done + 20)
            monkeypatch.undo()
            await run.until(lambda: daemon.telemetry.complete_cycles >= done + 25)
            assert await run.stop() == 0
    (error,) = _named(logs, "cycle_error")
    assert error["stage"] == "record" and "recorder exploded" in error["error"]
    (back,) = _named(logs, "cycle_error_recovered")
    assert back["failures"] >= 20


async def test_an_exception_in_the_reload_handover_keeps_the_old_config(
        sim: ModbusSimController, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = write_config(tmp_path, sim.endpoint, time_scale=1.0)
    cfg = load_config(path)
    with structlog.testing.capture_logs() as logs:
        async with stepped_daemon(cfg) as run:
            daemon = run.daemon
            await run.until(lambda: daemon.telemetry.complete_cycles >= 3)

            def overflow(*_: object, **__: object) -> Cycle:
                raise OverflowError("int too large to convert to float")

            monkeypatch.setattr("compd.runtime.reload.handover", overflow)
            path.write_text(path.read_text().replace("slew_um_s = 1.0", "slew_um_s = 0.5"))
            kept = daemon.running.cycle
            daemon.request_reload()
            await run.until(lambda: bool(_named(logs, "reload_failed")))
            done = daemon.telemetry.complete_cycles
            await run.until(lambda: daemon.telemetry.complete_cycles >= done + 5)
            assert daemon.running.cycle is kept and daemon.running.cfg is cfg
            assert daemon.reloader.reloads == 0
            assert await run.stop() == 0
    (failed,) = _named(logs, "reload_failed")
    assert "OverflowError" in failed["reason"] and failed["kept"] == cfg.config_sha256


async def test_a_reload_beyond_a_bound_is_refused_by_name(
        sim: ModbusSimController, tmp_path: Path) -> None:
    """max_total_um = 1e308 then kill -HUP: the reload is refused, the daemon runs on."""
    path = write_config(tmp_path, sim.endpoint, time_scale=1.0)
    path.write_text(path.read_text() + ADAPTATION)
    cfg = load_config(path)
    with structlog.testing.capture_logs() as logs:
        async with stepped_daemon(cfg) as run:
            daemon = run.daemon
            await run.until(lambda: daemon.telemetry.complete_cycles >= 3)
            path.write_text(path.read_text().replace("max_total_um = 20.0",
                                                     "max_total_um = 1e308"))
            daemon.request_reload()
            await run.until(lambda: bool(_named(logs, "reload_failed")))
            done = daemon.telemetry.complete_cycles
            await run.until(lambda: daemon.telemetry.complete_cycles >= done + 5)
            assert await run.stop() == 0
    (failed,) = _named(logs, "reload_failed")
    assert failed["key"] == "adaptation.max_total_um" and "10000" in failed["reason"]


class _Hangable(RecordingDriver):
    """A recording driver the test makes hang (`hang`), each subclass its own way."""

    hang = False


async def _hang_then_answer(cfg: LoadedConfig, driver: _Hangable,
                            event: str) -> list[MutableMapping[str, Any]]:
    """A stepped daemon on `driver`: 3 cycles, then the driver hangs until `event`
    is logged (the daemon's task must still run), then it answers again and 3
    more cycles complete before a clean stop. The captured log lines."""
    with structlog.testing.capture_logs() as logs:
        async with stepped_daemon(cfg, driver=driver) as run:
            daemon, task = run.daemon, run.task
            await run.until(lambda: daemon.telemetry.complete_cycles >= 3)
            driver.hang = True
            await until(lambda: len(_named(logs, event)) >= 1 or task.done())
            assert not task.done(), task
            driver.hang = False
            done = daemon.telemetry.complete_cycles
            await run.until(lambda: daemon.telemetry.complete_cycles >= done + 3)
            assert await run.stop() == 0
    return logs


class _Raced(asyncio.CancelledError):
    """What asyncua's wait_for2 raises when a cancellation meets an answer that arrived
    at the same instant (CancelledWithResultError, a CancelledError subclass)."""


class _RacingDriver(_Hangable):
    """Reads that, once `hang` is set, never answer, and end as the library ends a
    request cancelled at the instant its answer came: with the subclass."""

    async def read(self, names: Sequence[str]) -> dict[str, Sample]:
        if self.hang:
            try:
                await asyncio.Event().wait()
            except asyncio.CancelledError:
                raise _Raced() from None
        return await super().read(names)


async def test_a_read_whose_library_races_the_cycles_deadline_is_a_failed_read(
        sim: ModbusSimController, tmp_path: Path) -> None:
    """The cycle's own read scope expires while the library is answering: the library's
    cancellation subclass is a timed-out read (held by the fault policy, logged once),
    not a cancellation of the daemon's loop (under load it ended `compd run` with
    exit 1 before its first complete cycle)."""
    cfg = load_config(write_config(tmp_path, sim.endpoint, time_scale=1.0))
    logs = await _hang_then_answer(cfg, _RacingDriver(build_driver(cfg)), "read_failed")
    # the hung read is the first failure (a busy machine may add a timeout of its own)
    failed = _named(logs, "read_failed")[0]
    assert failed["type"] == "TimeoutError", failed
    assert not _named(logs, "cycle_broken")


class _HangingWriteDriver(_Hangable):
    """Writes that, once `hang` is set, never end: a driver whose own request
    timeout was not kept."""

    async def write(self, values: Mapping[str, float]) -> None:
        if self.hang:
            await asyncio.Event().wait()
        await super().write(values)


async def test_a_write_the_driver_never_ends_fails_at_the_cycles_bound(
        sim: ModbusSimController, tmp_path: Path) -> None:
    """The cycle bounds its write as it bounds its read, not only through the driver's
    own timeout: a write that never ends is a failed write (counted, logged), the
    cycles go on, and writes go through again once the driver answers."""
    cfg = load_config(write_config(tmp_path, sim.endpoint, time_scale=1.0))
    logs = await _hang_then_answer(cfg, _HangingWriteDriver(build_driver(cfg)), "write_failed")
    failed = _named(logs, "write_failed")[0]
    assert "no answer within the cycle's" in str(failed), failed
    assert not _named(logs, "cycle_broken")
