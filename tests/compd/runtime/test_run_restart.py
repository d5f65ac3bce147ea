"""`compd run` as a subprocess against the simulated Modbus controller:
kill -9 and restart without a jump, SIGTERM with a checkpoint, ramp-to-zero
shutdown, and a bad config refused with 78 before any connection."""

from __future__ import annotations

import asyncio
import itertools
import os
import signal
import socket
import sys
from pathlib import Path

import pytest

from compd.core.output import Status
from compd.runtime.checkpoint import load_checkpoint
from tests.configs import write_config
from tests.faults.daemon_run import ROOT, RecordingSim, start_daemon
from tests.harness import until_output

SLEW_UM_S = 1.0
PERIOD_S = 1.0
#: real processes in real time: a 100 ms period and a 50 ms request timeout, so
#: that a loaded machine's late answer is not a failed read (which holds the
#: offset, and a long run of them ends in the fault policy)
TIME_SCALE = 10.0
TIMEOUT_S = 0.05


def _assert_slew_limited(offsets: list[float]) -> None:
    steps = [abs(b - a) for a, b in itertools.pairwise(offsets)]
    # per cycle the output moves at most slew·Δt, Δt capped at two periods
    assert max(steps) <= 2 * SLEW_UM_S * PERIOD_S + 1e-3, max(steps)


async def test_kill_9_and_restart_resume_without_a_jump(rec: RecordingSim, tmp_path: Path) -> None:
    config = write_config(tmp_path, rec.sim.endpoint, checkpoint_every=5,
                          time_scale=TIME_SCALE, timeout_s=TIMEOUT_S)
    log = tmp_path / "daemon.log"
    proc = await start_daemon(config, log)
    try:
        await until_output(rec.sim, "heartbeat", lambda v: v >= 5, proc, log)
        await rec.sim.publish({"bearing": 22.5})  # the model wants ≈ +40 µm
        await until_output(rec.sim, "offset", lambda v: v >= 6.0, proc, log)
        proc.send_signal(signal.SIGKILL)
        assert await proc.wait() == -signal.SIGKILL
        killed_at = rec.offsets[-1]
        await asyncio.sleep(0.2)  # the controller keeps the offset meanwhile

        proc = await start_daemon(config, log)
        await until_output(rec.sim, "offset", lambda v: v >= killed_at + 4.0, proc, log)
        proc.send_signal(signal.SIGTERM)
        assert await asyncio.wait_for(proc.wait(), 120.0) == 0
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
    text = log.read_text()
    assert "checkpoint_restored" in text
    _assert_slew_limited(rec.offsets)
    state = load_checkpoint(tmp_path / "state" / "checkpoint.json")
    assert state is not None
    assert state["offset_um"] == pytest.approx((await rec.sim.outputs())["offset"], abs=1e-3)


async def test_sigterm_ramp_to_zero_then_exit_0(rec: RecordingSim, tmp_path: Path) -> None:
    config = write_config(tmp_path, rec.sim.endpoint, shutdown="ramp_to_zero",
                          time_scale=TIME_SCALE, timeout_s=TIMEOUT_S)
    log = tmp_path / "daemon.log"
    proc = await start_daemon(config, log)
    try:
        await until_output(rec.sim, "heartbeat", lambda v: v >= 5, proc, log)
        await rec.sim.publish({"bearing": 21.0})
        await until_output(rec.sim, "offset", lambda v: v >= 8.0, proc, log)
        proc.send_signal(signal.SIGTERM)
        assert await asyncio.wait_for(proc.wait(), 120.0) == 0
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
    assert (await rec.sim.outputs())["offset"] == 0.0
    _assert_slew_limited(rec.offsets)
    peak = rec.offsets.index(max(rec.offsets))
    tail = rec.offsets[peak:]
    assert all(b <= a for a, b in itertools.pairwise(tail))
    state = load_checkpoint(tmp_path / "state" / "checkpoint.json")
    assert state is not None and state["offset_um"] == 0.0
    assert "shutdown_ramp_finished" in log.read_text()


async def test_bad_config_exits_78_naming_the_key_without_connecting(tmp_path: Path) -> None:
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(4)
    listener.setblocking(False)
    try:
        port = listener.getsockname()[1]
        config = write_config(tmp_path, f"modbus://127.0.0.1:{port}")
        config.write_text(config.read_text().replace("limit_um = 100.0", "limit_um = 0"))
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "compd", "run", str(config),
            stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
            env={**os.environ, "PYTHONPATH": str(ROOT)}, cwd=str(ROOT))
        _, err = await proc.communicate()
        assert proc.returncode == 78
        assert "output.limit_um" in err.decode()
        with pytest.raises(BlockingIOError):
            listener.accept()  # nobody connected
    finally:
        listener.close()


async def test_usr1_usr2_are_logged_not_fatal(rec: RecordingSim, tmp_path: Path) -> None:
    """SIGUSR1 and SIGUSR2 are logged and the daemon runs on (their default would end
    it at once, with no checkpoint)."""
    config = write_config(tmp_path, rec.sim.endpoint, checkpoint_every=5)
    log = tmp_path / "daemon.log"
    proc = await start_daemon(config, log)
    try:
        await until_output(rec.sim, "heartbeat", lambda v: v >= 3, proc, log)
        for sig in (signal.SIGUSR1, signal.SIGUSR2):
            proc.send_signal(sig)
        beat = (await rec.sim.outputs())["heartbeat"]
        await until_output(rec.sim, "heartbeat", lambda v: v >= beat + 5, proc, log)
        assert proc.returncode is None
        proc.send_signal(signal.SIGTERM)
        assert await proc.wait() == 0
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
    text = await asyncio.to_thread(log.read_text)
    ignored = [ln for ln in text.splitlines() if '"signal_ignored"' in ln]
    assert {s for s in ("SIGUSR1", "SIGUSR2") if any(s in ln for ln in ignored)} \
        == {"SIGUSR1", "SIGUSR2"}
    assert load_checkpoint(tmp_path / "state" / "checkpoint.json") is not None


async def test_closed_stderr_and_a_taken_metrics_port_do_not_stop_compensation(
        rec: RecordingSim, tmp_path: Path) -> None:
    """`compd run 2>&-` exited 1 silently; a metrics port in use was a traceback."""
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        config = write_config(tmp_path, rec.sim.endpoint, time_scale=TIME_SCALE,
                              timeout_s=TIMEOUT_S)
        config.write_text(config.read_text() + f"metrics_port = {port}\n")
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        env.pop("NOTIFY_SOCKET", None)
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-c",
            "import os, sys; os.close(2); from compd.cli import main; sys.exit(main())",
            "run", str(config), stdout=asyncio.subprocess.DEVNULL, env=env, cwd=str(ROOT))
        log = tmp_path / "none.log"
        log.write_text("(stderr closed: no log)")
        try:
            await until_output(rec.sim, "heartbeat", lambda v: v >= 5, proc, log)
            # compensating: a cycle with status OK (one late answer holds a cycle)
            await until_output(rec.sim, "status", lambda v: int(v) & Status.OK, proc, log)
            proc.send_signal(signal.SIGTERM)
            assert await proc.wait() == 0
        finally:
            if proc.returncode is None:
                proc.kill()
                await proc.wait()
