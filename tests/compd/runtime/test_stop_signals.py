"""Every signal whose default action would end compd is handled: SIGALRM, SIGPWR,
SIGVTALRM, SIGPROF, SIGIO, SIGXCPU, SIGSTKFLT stop it as SIGTERM does, naming the
signal (their default would end it at once, exit 128+n, with no log line, no
checkpoint and no shutdown policy); SIGXFSZ (like SIGUSR1/2) is logged and
ignored."""

from __future__ import annotations

import asyncio
import itertools
import json
import os
import signal
from pathlib import Path

import pytest
import structlog

from compd.config.loader import load_config
from compd.runtime import signals
from compd.runtime.checkpoint import load_checkpoint
from compd.runtime.fleet import Fleet, load_machines
from compd.runtime.sdnotify import Notifier
from compd.testing import SteppedClock
from drivers.sim.modbus_server import ModbusSimController
from tests.compd.runtime.test_run_dir import _complete, _machines_dir, sims  # noqa: F401 - the fixture
from tests.configs import write_config
from tests.faults.daemon_run import RecordingSim, start_daemon
from tests.harness import Fleetstep, stepped_daemon, until_output

#: the signals whose default ends the process, and the two SIGTERM always stopped on
STOPPING = ["SIGALRM", "SIGPWR", "SIGVTALRM", "SIGPROF", "SIGIO", "SIGXCPU", "SIGSTKFLT",
            "SIGTERM", "SIGINT"]


def _installed(sig: signal.Signals) -> bool:
    """A handler of the loop's is in place (sending the signal otherwise would end the
    test process itself, as it ended compd)."""
    return signal.getsignal(sig) not in (signal.SIG_DFL, None)


@pytest.mark.parametrize("name", STOPPING)
async def test_each_terminating_signal_stops_like_sigterm(
        sim: ModbusSimController, tmp_path: Path, name: str) -> None:
    sig = signal.Signals[name]
    cfg = load_config(write_config(tmp_path, sim.endpoint, checkpoint_every=100000,
                                   time_scale=1.0))
    with structlog.testing.capture_logs() as logs:
        async with stepped_daemon(cfg) as run:
            daemon = run.daemon
            await run.until(lambda: daemon.telemetry.complete_cycles >= 3)
            assert _installed(sig), f"{name} would end compd at once"
            os.kill(os.getpid(), sig)
            assert await asyncio.wait_for(run.task, 20.0) == 0
    assert not _installed(sig) or signal.getsignal(sig) is signal.default_int_handler
    (got,) = [e for e in logs if e["event"] == "signal_received"]
    assert got["signal"] == name and got["action"] == "stop"
    assert got["log_level"] == ("info" if name in ("SIGTERM", "SIGINT") else "warning")
    (stop,) = [e for e in logs if e["event"] == "shutdown_requested"]
    assert stop["signal"] == name and stop["policy"] == "hold"
    (stopped,) = [e for e in logs if e["event"] == "daemon_stopped"]
    assert stopped["signal"] == name
    state = load_checkpoint(cfg.state_dir / "checkpoint.json")  # written at the stop
    assert state is not None and state["sequence"] == daemon.loop.cycles


async def test_sigxfsz_is_logged_and_ignored(sim: ModbusSimController, tmp_path: Path) -> None:
    cfg = load_config(write_config(tmp_path, sim.endpoint, time_scale=1.0))
    with structlog.testing.capture_logs() as logs:
        async with stepped_daemon(cfg) as run:
            daemon = run.daemon
            await run.until(lambda: daemon.telemetry.complete_cycles >= 3)
            assert _installed(signal.SIGXFSZ)
            os.kill(os.getpid(), signal.SIGXFSZ)
            done = daemon.telemetry.complete_cycles
            await run.until(lambda: daemon.telemetry.complete_cycles >= done + 5)
            assert not run.task.done()
            assert await run.stop() == 0
    assert [e["signal"] for e in logs if e["event"] == "signal_ignored"] == ["SIGXFSZ"]


def test_the_lists_cover_every_signal_that_would_end_compd() -> None:
    handled = set(signals.STOP) | set(signals.IGNORED) | {signal.SIGHUP}
    assert {signal.Signals[n] for n in STOPPING} <= set(signals.STOP)
    assert {signal.SIGUSR1, signal.SIGUSR2, signal.SIGXFSZ} <= set(signals.IGNORED)
    # the rest end the process by design: uncatchable, a core on request, or a fault
    left = {signal.SIGKILL, signal.SIGSTOP, signal.SIGQUIT, signal.SIGPIPE, signal.SIGSEGV,
            signal.SIGBUS, signal.SIGILL, signal.SIGFPE, signal.SIGABRT, signal.SIGSYS,
            signal.SIGTRAP}
    ignored_by_default = {signal.SIGCHLD, signal.SIGCONT, signal.SIGURG, signal.SIGWINCH,
                          signal.SIGTSTP, signal.SIGTTIN, signal.SIGTTOU}
    realtime = {s for s in signal.Signals if signal.SIGRTMIN <= s <= signal.SIGRTMAX}
    assert set(signal.Signals) - handled - left - ignored_by_default - realtime == set()


#: the real daemon's slew (µm per s, at time scale 1 a cycle's step)
SLEW_UM_S = 8.0


def _events(log: Path, name: str) -> list[dict[str, object]]:
    return [json.loads(ln[ln.index("{"):]) for ln in log.read_text().splitlines()
            if f'"{name}"' in ln]


@pytest.mark.parametrize(("name", "shutdown"), [("SIGXCPU", "ramp_to_zero"),
                                                ("SIGPWR", "hold")])
async def test_a_real_daemon_stops_on_it_with_its_shutdown_policy(
        rec: RecordingSim, tmp_path: Path, name: str, shutdown: str) -> None:
    """`compd run` in real time, where a request has 0.4 s (time scale 1: a loaded
    machine answers within it; at the sim's default 8 ms a write timed out but applied
    leaves the controller holding an offset the checkpoint never confirmed), and a
    slew of 8 µm/s so that the warm-up and the ramp take a few cycles."""
    config = write_config(tmp_path, rec.sim.endpoint, shutdown=shutdown, time_scale=1.0,
                          slew_um_s=SLEW_UM_S)
    log = tmp_path / "daemon.log"
    proc = await start_daemon(config, log)
    try:
        await until_output(rec.sim, "heartbeat", lambda v: v >= 3, proc, log)
        await rec.sim.publish({"bearing": 21.0})  # sp2 wants ≈ +16 µm
        await until_output(rec.sim, "offset", lambda v: v >= 8.0, proc, log)
        proc.send_signal(signal.Signals[name])
        assert await asyncio.wait_for(proc.wait(), 30.0) == 0  # not 128 + n
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
    (got,) = _events(log, "signal_received")
    assert got["signal"] == name and got["level"] == "warning"
    (stop,) = _events(log, "shutdown_requested")
    assert stop["policy"] == shutdown and stop["signal"] == name
    held = (await rec.sim.outputs())["offset"]
    state = load_checkpoint(tmp_path / "state" / "checkpoint.json")
    assert state is not None and state["offset_um"] == pytest.approx(held, abs=1e-3)
    if shutdown == "ramp_to_zero":
        assert held == 0.0 and _events(log, "shutdown_ramp_finished")
        steps = [abs(b - a) for a, b in itertools.pairwise(rec.offsets)]
        assert max(steps) <= 2 * SLEW_UM_S + 1e-3
    else:
        assert held >= 8.0  # held where it was


async def test_run_dir_stops_every_machine_on_sigxcpu(
        sims: list[ModbusSimController], tmp_path: Path) -> None:  # noqa: F811
    """`compd run DIR` installed only TERM, INT and HUP: XCPU ended every machine at once.
    The machines in lockstep (their files' 1 s period is one tick of the clock)."""
    clock = SteppedClock(period_s=1.0)
    fleet = Fleet(load_machines(_machines_dir(tmp_path, sims)), notifier=Notifier(None),
                  clock=clock, sleep=clock.sleep)
    with structlog.testing.capture_logs() as logs:
        task = asyncio.get_running_loop().create_task(fleet.run())
        steps = Fleetstep(clock, task)
        await steps.until_asleep(len(sims))  # every machine ran its first cycle
        await steps.step(2)
        assert min(_complete(fleet).values()) >= 3
        assert _installed(signal.SIGXCPU) and _installed(signal.SIGUSR1)
        os.kill(os.getpid(), signal.SIGUSR1)  # logged, nothing else
        os.kill(os.getpid(), signal.SIGXCPU)
        assert await asyncio.wait_for(task, 20.0) == 0
    assert [e["signal"] for e in logs if e["event"] == "signal_received"] == ["SIGXCPU"]
    assert [e["signal"] for e in logs if e["event"] == "signal_ignored"] == ["SIGUSR1"]
    stopped = [e for e in logs if e["event"] == "daemon_stopped"]
    assert len(stopped) == len(sims) and {e["signal"] for e in stopped} == {"SIGXCPU"}
    for name in _complete(fleet):
        assert load_checkpoint(tmp_path / "machines.d" / f"state-{name}" /
                               "checkpoint.json") is not None
