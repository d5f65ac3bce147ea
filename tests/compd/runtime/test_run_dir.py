"""`compd run DIR`: several machines in one process (compd.runtime.fleet), each its
own failure domain, against simulated Modbus controllers on 127.0.0.1.

The behaviour (a stopped controller, a crash and its restart, the staggered
start) runs in-process in lockstep: every machine's daemon on one
`compd.testing.SteppedClock` (`tests.harness.Fleetstep`), the real drivers
and servers between, so counts of cycles are exact and a loaded machine only
makes the tests slower. One real-process smoke test (SIGTERM) stays, asserting
nothing a slow machine could change."""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
import sys
import urllib.request
from collections.abc import AsyncIterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import pytest

from compd.cli import main
from compd.config.loader import load_config
from compd.runtime.fleet import Fleet, load_machines
from compd.runtime.startup import checkpoint_path
from compd.testing import SteppedClock
from drivers.base import Sample
from drivers.sim.modbus_server import ModbusSimController
from drivers.sim.ports import free_tcp_port
from tests.configs import write_config
from tests.harness import Fleetstep, modbus_sims

NAMES = ("mill-a", "mill-b", "mill-c")


def _write_machine(directory: Path, name: str, endpoint: str, *, checkpoint_every: int = 20,
                   metrics_port: int | None = None, time_scale: float = 1.0,
                   timeout_s: float = 0.5) -> Path:
    """One machine's file; by default for lockstep (the stepped clock counts
    machine seconds, a request may take half a period of real time)."""
    metrics = () if metrics_port is None else [
        ("[telemetry]", f"[telemetry]\nmetrics_port = {metrics_port}")]
    return write_config(directory, endpoint, filename=f"{name}.toml", name=name,
                        dir=f"state-{name}", time_scale=time_scale, timeout_s=timeout_s,
                        checkpoint_every=checkpoint_every, swap=metrics)


@pytest.fixture
async def sims() -> AsyncIterator[list[ModbusSimController]]:
    async with modbus_sims(len(NAMES)) as controllers:
        yield controllers


def _machines_dir(tmp_path: Path, sims: Sequence[ModbusSimController], **kw: Any) -> Path:
    d = tmp_path / "machines.d"
    d.mkdir()
    for name, sim in zip(NAMES, sims, strict=True):
        _write_machine(d, name, sim.endpoint, **kw)
    return d


def _complete(fleet: Fleet) -> dict[str, int]:
    return {n: (d.telemetry.complete_cycles if (d := fleet.daemons.get(n)) else 0) for n in NAMES}


async def _stop(fleet: Fleet, task: asyncio.Task[int]) -> int:
    """Stop every machine (hold: each ends after the cycle the request wakes,
    no step needed) and return the fleet's status."""
    fleet.request_stop()
    return await asyncio.wait_for(task, 120.0)


def _lockstep(configs: list[Any], **kwargs: Any) -> tuple[Fleet, asyncio.Task[int], Fleetstep]:
    clock = SteppedClock(period_s=1.0)
    fleet = Fleet(configs, clock=clock, sleep=clock.sleep, **kwargs)
    task = asyncio.get_running_loop().create_task(fleet.run())
    return fleet, task, Fleetstep(clock, task)


async def test_a_stopped_controller_never_holds_up_the_others(
        sims: list[ModbusSimController], tmp_path: Path) -> None:
    port = free_tcp_port("127.0.0.1")
    fleet, task, fs = _lockstep(load_machines(_machines_dir(tmp_path, sims, metrics_port=port)))
    try:
        await fs.until_asleep(len(NAMES))  # every machine ran its first cycle
        await fs.step(4)
        assert _complete(fleet) == dict.fromkeys(NAMES, 5)
        down = sims[1]
        await down.stop()  # mill-b's controller goes away
        await fs.step()
        assert fleet.daemons["mill-b"].io.read_ok is False
        before = _complete(fleet)
        beats = [(await s.outputs())["heartbeat"] for s in (sims[0], sims[2])]
        await fs.step(50)
        after = _complete(fleet)
        assert after["mill-b"] == before["mill-b"]  # it holds, writes nothing
        # every period stepped was a cycle of each of the others
        assert {n: after[n] - before[n] for n in ("mill-a", "mill-c")} == {
            "mill-a": 50, "mill-c": 50}
        # the controllers of the others saw their heartbeats advance all along
        for sim, beat in zip((sims[0], sims[2]), beats, strict=True):
            assert (await sim.outputs())["heartbeat"] != beat
        # one endpoint, every machine's series labelled with its name
        body = await asyncio.to_thread(
            lambda: urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics",
                                           timeout=30).read().decode())
        for name in NAMES:
            assert f'compd_cycles_complete_total{{machine="{name}"}}' in body
            assert f'compd_machine_running{{machine="{name}"}} 1.0' in body
        await down.start()  # back on the same port: mill-b resumes
        # the driver's reconnect attempt, made now (its backoff runs on real time,
        # which lockstep never waits on)
        driver = fleet.daemons["mill-b"].running.driver
        assert driver is not None
        await driver.connect()
        resumed = _complete(fleet)["mill-b"]
        await fs.step(10)
        assert _complete(fleet)["mill-b"] == resumed + 10
        assert await _stop(fleet, task) == 0
    finally:
        if not task.done():
            await _stop(fleet, task)
    assert fleet.restarts == dict.fromkeys(NAMES, 0)  # a controller's fault is no crash


class _CrashingDriver:
    """A driver whose read fails with an error no driver should raise: a bug."""

    protocol = "modbus"
    connected = True

    async def connect(self) -> None:
        return None

    async def read(self, names: Sequence[str]) -> dict[str, Sample]:
        raise RuntimeError("a bug in a driver")

    async def write(self, values: Mapping[str, float]) -> None:
        return None

    async def close(self) -> None:
        return None


async def test_a_crashing_daemon_is_restarted_alone(
        sims: list[ModbusSimController], tmp_path: Path) -> None:
    configs = load_machines(_machines_dir(tmp_path, sims))
    fleet, task, fs = _lockstep(configs, drivers={"mill-c": _CrashingDriver()})
    try:
        # mill-c crashes at its first read (before its first sleep) and is started
        # again after its backoff (1 s of real time) with a real driver: three
        # sleeps are mill-a's, mill-b's and the new mill-c's first
        await fs.until_asleep(len(NAMES))
        assert fleet.restarts == {"mill-a": 0, "mill-b": 0, "mill-c": 1}
        await fs.step(5)
        assert _complete(fleet) == {"mill-a": 6, "mill-b": 6, "mill-c": 6}
        assert fleet.restarts == {"mill-a": 0, "mill-b": 0, "mill-c": 1}
        assert await _stop(fleet, task) == 0
    finally:
        if not task.done():
            await _stop(fleet, task)


def test_a_bad_file_refuses_the_whole_start_naming_it(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    d = tmp_path / "machines.d"
    d.mkdir()
    for name in NAMES:
        _write_machine(d, name, "modbus://127.0.0.1:1502")
    bad = d / "mill-b.toml"
    bad.write_text(bad.read_text().replace("limit_um = 100.0", "limit_um = 0.0"))
    assert main(["run", str(d)]) == 78
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and str(bad) in err and "limit_um" in err
    assert str(d / "mill-a.toml") not in err
    assert not any((d / f"state-{n}").exists() for n in NAMES)  # nothing ran


def test_two_files_sharing_a_state_dir_are_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    d = tmp_path / "machines.d"
    d.mkdir()
    for name in NAMES:
        _write_machine(d, name, "modbus://127.0.0.1:1502")
    c = d / "mill-c.toml"
    c.write_text(c.read_text().replace('dir = "state-mill-c"', 'dir = "state-mill-a"'))
    assert main(["run", str(d)]) == 78
    err = capsys.readouterr().err
    assert str(c) in err and str(d / "mill-a.toml") in err and "state" in err


def test_an_empty_directory_is_refused(tmp_path: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["run", str(tmp_path)]) == 78
    assert "no *.toml" in capsys.readouterr().err


async def test_sigterm_stops_every_machine_with_its_checkpoint(
        sims: list[ModbusSimController], tmp_path: Path) -> None:
    # a real process in real time: a 200 ms period, a 100 ms request timeout
    d = _machines_dir(tmp_path, sims, checkpoint_every=1_000_000,  # only at the stop
                      time_scale=5.0, timeout_s=0.1)
    paths = [checkpoint_path(load_config(d / f"{n}.toml")) for n in NAMES]
    env = {**os.environ, "NOTIFY_SOCKET": ""}
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "compd", "run", str(d), "--workers", "1", env=env,
        stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.PIPE)
    try:
        for sim in sims:  # every machine is writing its heartbeat (a generous bound)
            for _ in range(12_000):
                if (await sim.outputs())["heartbeat"] > 3 or proc.returncode is not None:
                    break
                await asyncio.sleep(0.01)
            assert (await sim.outputs())["heartbeat"] > 3
        assert not any(p.exists() for p in paths)
        proc.send_signal(signal.SIGTERM)
        _, err = await asyncio.wait_for(proc.communicate(), 120.0)
        assert proc.returncode == 0, err.decode()[-2000:]
        assert all(p.exists() for p in paths)
        log = err.decode()
        for name in NAMES:
            assert f'"machine": "{name}"' in log
        assert log.count('"event": "daemon_stopped"') == 3
    finally:
        if proc.returncode is None:
            with contextlib.suppress(ProcessLookupError):
                proc.kill()
            await proc.wait()


async def test_machines_start_one_after_the_other_with_their_cycles_spread(
        sims: list[ModbusSimController], tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Started together, every machine's deadline would fall on the same instant
    and their start-ups would hold the loop at once (`staggered_starts`)."""
    import time

    from compd.core.schedule import START_SPACING_S, staggered_starts
    from compd.runtime.daemon import Daemon

    started: dict[str, float] = {}
    serve = Daemon.serve

    async def timed(self: Daemon) -> int:
        started[self.running.cfg.raw.machine.name] = time.monotonic()
        return await serve(self)

    monkeypatch.setattr(Daemon, "serve", timed)
    # the real period the plan spreads over is 20 ms; the start delays run on real
    # time, the machines' cycles on the stepped clock (nothing else waits)
    configs = load_machines(_machines_dir(tmp_path, sims, time_scale=50.0, timeout_s=0.01))
    t0 = time.monotonic()
    fleet, task, fs = _lockstep(configs)
    try:
        await fs.until_asleep(len(NAMES))  # every machine started and ran a cycle
    finally:
        assert await _stop(fleet, task) == 0
    period = configs[0].real_period_s
    delays = staggered_starts(len(NAMES), period)
    assert delays[1] >= START_SPACING_S
    # in name order, each never sooner than planned (a busy loop may only be later)
    times = [started[n] - t0 for n in sorted(NAMES)]
    assert times == sorted(times)
    assert all(t >= d - 0.002 for t, d in zip(times, delays, strict=True))
    # the plan itself: every phase of the period taken once
    assert sorted(round(d / period * 3) % 3 for d in delays) == [0, 1, 2]


async def test_a_restart_after_a_reload_runs_the_reloaded_config_with_fresh_model_state(
        sims: list[ModbusSimController], tmp_path: Path) -> None:
    """A machine reloaded by SIGHUP that then crashes comes back on the config it
    ran (the reloaded one, not the file as read at start), and its new cycle steps a
    model of its own, not the object the dead cycle was stepping."""
    d = tmp_path / "machines.d"
    d.mkdir()
    path = _write_machine(d, "mill-a", sims[0].endpoint)
    fleet, task, fs = _lockstep(load_machines(d))
    try:
        await fs.until_asleep(1)
        await fs.step(3)
        path.write_text(path.read_text().replace('file = "sp2"', 'file = "sp1"'))
        reloaded = load_config(path)
        daemon = fleet.daemons["mill-a"]
        daemon.request_reload()
        assert daemon.reloader.task is not None
        await daemon.reloader.task  # prepared beside the loop; swapped in at the next cycle
        await fs.step()
        assert daemon.reloader.reloads == 1
        assert daemon.running.cfg.model_sha256 == reloaded.model_sha256
        assert daemon.running.cycle is not None
        dead_model = daemon.running.cycle.models.model
        daemon.running.driver = _CrashingDriver()  # its next read is a bug: a crash
        await fs.step()  # the crash, the backoff (real time), the new daemon's first cycle
        assert fleet.restarts == {"mill-a": 1}
        again = fleet.daemons["mill-a"]
        assert again is not daemon and again.running.cycle is not None
        assert again.running.cfg.model_sha256 == reloaded.model_sha256
        assert again.running.cfg.model.name == "SP1 per-spindle"
        assert again.running.cycle.models.model is not dead_model
        # the config stays a description
        assert again.running.cycle.models.model is not again.running.cfg.model
        assert again.running.cfg.model.references == {}  # never stepped: no reference state set
        await fs.step(2)
        assert again.telemetry.complete_cycles >= 2
        assert await _stop(fleet, task) == 0
    finally:
        if not task.done():
            await _stop(fleet, task)
