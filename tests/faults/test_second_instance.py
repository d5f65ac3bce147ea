"""A second `compd run` on a state directory that a running daemon holds is
refused at once (exit 75, EX_TEMPFAIL, naming the directory and the holder's
pid) instead of queueing for the lock, and the first daemon goes on
compensating undisturbed.

"At once" is not timed (a loaded machine takes over a second to start Python):
a second instance that waited for the lock would wait for as long as the first
daemon runs, so a bound far beyond any start-up tells the two apart."""

from __future__ import annotations

import asyncio
import sys
from pathlib import Path

import pytest

from compd.cli import main
from compd.runtime.checkpoint import load_checkpoint
from compd.sysexits import EX_TEMPFAIL
from tests.configs import write_config
from tests.faults.daemon_run import (
    ROOT,
    RecordingSim,
    daemon_env,
    forget_daemon_logging,
    heartbeat,
    kill_and_wait,
    start_daemon,
)
from tests.harness import until

#: far beyond a start-up on a busy machine; a second instance that queued for
#: the lock would still be waiting (the first daemon runs until the test ends)
REFUSED_BEFORE_S = 60.0


async def test_second_instance_refused_not_queued(rec: RecordingSim, tmp_path: Path) -> None:
    config = write_config(tmp_path, rec.sim.endpoint, checkpoint_every=5)
    log = tmp_path / "first.log"
    first = await start_daemon(config, log)
    try:
        await until(lambda: _hb_at_least(rec, 3), first, log, "first daemon cycling")
        second = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "compd", "run", str(config),
            stdin=asyncio.subprocess.DEVNULL, stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.PIPE, env=daemon_env(), cwd=str(ROOT))
        try:
            _out, err = await asyncio.wait_for(second.communicate(), REFUSED_BEFORE_S)
        finally:
            await kill_and_wait(second)
        assert second.returncode == EX_TEMPFAIL, err.decode()
        text = err.decode()
        assert str(tmp_path / "state") in text and str(first.pid) in text, text
        assert "in use" in text, text
        # the holder was not disturbed: it keeps cycling and writing
        hb = await heartbeat(rec.sim)
        n = len(rec.writes)
        await until(lambda: _hb_at_least(rec, hb + 3), first, log, "first daemon still cycling")
        assert len(rec.writes) > n
        assert first.returncode is None
    finally:
        await kill_and_wait(first)
    load_checkpoint(tmp_path / "state" / "checkpoint.json")  # intact (raises if torn)


async def _hb_at_least(rec: RecordingSim, n: float) -> bool:
    return await heartbeat(rec.sim) >= n


async def test_in_process_run_refused_while_a_daemon_holds_the_dir(
        rec: RecordingSim, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = write_config(tmp_path, rec.sim.endpoint)
    log = tmp_path / "first.log"
    first = await start_daemon(config, log)
    try:
        await until(lambda: _hb_at_least(rec, 2), first, log, "first daemon cycling")
        rc = await asyncio.to_thread(main, ["run", str(config)])
    finally:
        forget_daemon_logging()
        await kill_and_wait(first)
    assert rc == EX_TEMPFAIL
    assert f"in use by pid {first.pid}" in capsys.readouterr().err
