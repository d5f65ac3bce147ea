"""A foreign offset of 1000.0 µm makes the daemon hold its output: every source
of health must then say unhealthy, together: the metrics (fault state 3,
`health --url` red), `health --state-dir` (the container's HEALTHCHECK) and the
recorder, which counts no held cycle as complete.

A complete cycle is one whose offset is the one compd wants, in force
(`compd.core.cycle.offset_in_force`); the daemon writes a checkpoint as soon
as it enters or leaves the alarm, so the state directory follows at once."""

from __future__ import annotations

import asyncio
import json
import sqlite3
import subprocess
import sys
from pathlib import Path

from compd.core.output import Status
from drivers.sim.ports import free_tcp_port
from tests.configs import write_config
from tests.faults.daemon_run import (
    ROOT,
    RecordingSim,
    daemon_env,
    heartbeat,
    kill_and_wait,
    start_daemon,
)
from tests.harness import until

from .test_foreign_offset import _foreign_write, _status, _write_until_held


def _health(*argv: str) -> tuple[int, str]:
    proc = subprocess.run([sys.executable, "-m", "compd", "health", *argv, "--max-age-s", "60",
                           "--timeout-s", "5"], capture_output=True, text=True, check=False,
                          timeout=60, cwd=ROOT, env=daemon_env())
    assert "Traceback" not in proc.stderr, proc.stderr
    return proc.returncode, proc.stdout.strip()


async def _healthy_again(proc: asyncio.subprocess.Process, *argv: str) -> tuple[int, str]:
    """`compd health` while the daemon is healthy. On a loaded PC one read may time
    out (50 ms) and make one instant rightly unhealthy (controller_not_answering),
    so the check is asked again, a bounded number of times, while the daemon runs
    on; the last answer is returned for the test to judge."""
    for _ in range(30):
        got = await asyncio.to_thread(_health, *argv)
        if got[0] == 0 or proc.returncode is not None:
            break
    return got


def _last_cause(state_dir: Path) -> object:
    try:
        return json.loads((state_dir / "checkpoint.json").read_text()).get("last_cause")
    except (OSError, ValueError):
        return None


def _last_state(state_dir: Path) -> object:
    try:
        return json.loads((state_dir / "checkpoint.json").read_text()).get("last_state")
    except (OSError, ValueError):
        return None


async def test_a_held_output_is_unhealthy_by_every_source(rec: RecordingSim,
                                                          tmp_path: Path) -> None:
    # 10x with a 50 ms request timeout: a loaded machine's late answer is not a
    # failed read that turns "healthy while ok" into a held cycle at the instant read
    # a slew of 4 µm/s: the ramp back to about 80 µm after the clear takes 20 cycles
    config = write_config(tmp_path, rec.sim.endpoint, time_scale=10.0, slew_um_s=4.0,
                          timeout_s=0.05)
    port = free_tcp_port("127.0.0.1")
    config.write_text(config.read_text() + f"metrics_port = {port}\n")
    url = f"http://127.0.0.1:{port}/metrics"
    state = tmp_path / "state"
    log = tmp_path / "daemon.log"
    modbus_port = int(rec.sim.endpoint.rsplit(":", 1)[1])
    proc = await start_daemon(config, log)
    try:
        await until(lambda: len(rec.writes) > 0, proc, log, "first write")
        # after the start: the model sees it heat, to about 80 µm, within the 100 µm limit
        # (a model beyond it is clamped, and the limit in force is not what it wants)
        await rec.sim.publish({"bearing": 25.0})
        await until(lambda: rec.offsets and rec.offsets[-1] > 5.0, proc, log, "compensating")
        await until(lambda: _last_state(state) == "ok", proc, log, "a checkpoint while ok")
        before = await _healthy_again(proc, "--state-dir", str(state))
        before_url = await _healthy_again(proc, "--url", url)

        await _write_until_held(rec, modbus_port, 1000.0, proc, log)
        await until(lambda: _last_state(state) == "held", proc, log, "the alarm checkpointed")
        hb = await heartbeat(rec.sim)
        await until(lambda: _hb_past(rec, hb + 20), proc, log, "held cycles going on")
        held = await asyncio.to_thread(_health, "--state-dir", str(state))
        held_url = await asyncio.to_thread(_health, "--url", url)
        assert await _status(rec) & Status.OFFSET_HELD

        cleared_at = len(rec.writes)
        await _foreign_write(modbus_port, 0.0)  # an operator clears the register
        await until(lambda: len(rec.writes) > cleared_at + 10, proc, log, "writing again")
        await until(lambda: _last_state(state) == "ok", proc, log, "the recovery checkpointed")
        # ramping back from the cleared value is an alarm (READBACK_MISMATCH): the offset
        # compd wants is in force, and healthy, once the ramp is done
        await until(lambda: _last_cause(state) == "in_force", proc, log, "the ramp back done")
        after = await _healthy_again(proc, "--state-dir", str(state))
        proc.terminate()
        assert await asyncio.wait_for(proc.wait(), 120.0) == 0
    finally:
        await kill_and_wait(proc)

    print(f"before: {before} / {before_url}\nheld: {held} / {held_url}\nafter: {after}")
    assert before[0] == 0 and before_url[0] == 0, (before, before_url)
    assert held == (1, f"unhealthy: state dir {state}: fault state held (alarm/stopped)")
    assert held_url[0] == 1 and "fault state 3" in held_url[1]
    assert after[0] == 0 and after[1].startswith("healthy: state dir: last complete cycle")

    with sqlite3.connect(state / "samples.sqlite") as db:
        by_state = dict(db.execute(
            "SELECT state, SUM(complete) FROM samples GROUP BY state").fetchall())
        n_held = db.execute("SELECT COUNT(*) FROM samples WHERE state = 'held'").fetchone()[0]
        unconfirmed = db.execute("SELECT COUNT(*) FROM samples WHERE complete = 1"
                                 " AND (offset_um IS NULL OR valid = 0)").fetchone()[0]
    print(f"recorder: {n_held} held rows, complete by state {by_state}")
    assert n_held >= 20
    assert by_state["held"] == 0  # valid inputs, never complete
    assert by_state["ok"] > 0 and unconfirmed == 0


async def _hb_past(rec: RecordingSim, n: float) -> bool:
    return await heartbeat(rec.sim) >= n
