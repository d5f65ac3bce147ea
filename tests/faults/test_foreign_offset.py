"""A second Modbus client writes into the offset register while `compd run`
is compensating: an alarm, and never a step at the tool.

1000.0 (limit 100 µm) is beyond anything compd may write: the daemon raises
the alarm and writes no offset at all (heartbeat and status go on, the
status word says OFFSET_HELD + ALARM) while the register holds it; once a
client clears the register to 0 the daemon ramps from 0 at the slew limit.
Writing the clamped 99 µm on the next cycle would be a step of 901 µm at
the tool.
"""

from __future__ import annotations

import asyncio
import itertools
import math
from pathlib import Path

from pymodbus.client import AsyncModbusTcpClient

from compd.core.output import Status
from drivers.modbus_codec import encode
from drivers.sim.modbus_server import OUTPUTS, UNIT
from tests.configs import write_config
from tests.faults.daemon_run import RecordingSim, heartbeat, kill_and_wait, start_daemon
from tests.harness import tail, until

SLEW_UM_S = 2.0
PERIOD_S = 1.0
#: a real process in real time: a 100 ms period, a 50 ms request timeout, so a
#: loaded machine's late answer is not a failed read (a held cycle that writes
#: no offset where the test expects the ramp's first step)
TIME_SCALE = 10.0
TIMEOUT_S = 0.05


async def _foreign_write(port: int, value: float) -> None:
    """What a second writer does: one write-multiple into the offset register."""
    client = AsyncModbusTcpClient("127.0.0.1", port=port)
    try:
        assert await client.connect()
        rr = await client.write_registers(OUTPUTS["offset"].address,
                                          encode(OUTPUTS["offset"], value), device_id=UNIT)
        assert not rr.isError()
    finally:
        client.close()


async def _write_until_held(rec: RecordingSim, port: int, value: float,
                            proc: asyncio.subprocess.Process, log: Path) -> int:
    """The foreign write, made again until the daemon holds. A write that lands between
    the daemon's read and its own write of the same cycle is overwritten before the
    daemon could see it (the register is the daemon's; a second writer that means it
    writes again), so one write alone left the test waiting on a busy machine. Returns
    the count of offset writes before the last foreign one."""
    loop = asyncio.get_running_loop()
    last = {"at": len(rec.writes), "t": -math.inf}

    async def held_or_again() -> bool:
        if await _held(rec):
            return True
        if loop.time() - last["t"] >= 0.2:  # two of the daemon's periods at 10x
            last["at"], last["t"] = len(rec.writes), loop.time()
            await _foreign_write(port, value)
        return False

    await until(held_or_again, proc, log, "status OFFSET_HELD")
    return int(last["at"])


async def _status(rec: RecordingSim) -> int:
    return int((await rec.sim.outputs())["status"])


async def test_foreign_offset_is_held_then_ramped_from(rec: RecordingSim,
                                                       tmp_path: Path) -> None:
    config = write_config(tmp_path, rec.sim.endpoint, time_scale=TIME_SCALE,
                          slew_um_s=SLEW_UM_S, timeout_s=TIMEOUT_S)
    log = tmp_path / "daemon.log"
    port = int(rec.sim.endpoint.rsplit(":", 1)[1])
    proc = await start_daemon(config, log)
    try:
        await until(lambda: len(rec.writes) > 0, proc, log, "first write")
        await rec.sim.publish({"bearing": 30.0})
        await until(lambda: rec.offsets[-1] > 5.0, proc, log, "offset following the heat")
        before = rec.offsets[-1]
        foreign_at = await _write_until_held(rec, port, 1000.0, proc, log)
        hb = await heartbeat(rec.sim)
        await until(lambda: _hb_past(rec, hb + 10), proc, log, "heartbeat going on")
        assert await _status(rec) & Status.ALARM
        assert not await _status(rec) & Status.OK
        assert (await rec.sim.outputs())["offset"] == 1000.0
        # the only write into the offset since then is the foreign one
        assert rec.offsets[foreign_at:] == [1000.0]
        cleared_at = len(rec.writes)
        await _foreign_write(port, 0.0)  # an operator clears the register
        await until(lambda: len(rec.writes) > cleared_at + 10, proc, log, "writing again")
        proc.terminate()
        assert await asyncio.wait_for(proc.wait(), 120.0) == 0, await asyncio.to_thread(
            tail, log)
    finally:
        await kill_and_wait(proc)
    text = log.read_text()
    assert "readback_out_of_range" in text and "readback_in_range" in text
    ramp = rec.offsets[cleared_at:]
    assert ramp[0] == 0.0  # the operator's write
    steps = [abs(b - a) for a, b in itertools.pairwise(ramp)]
    # Δt capped at 2·Ts by the output stage: no step beyond R·2Ts from what the
    # controller holds, so the way back to `before` is a ramp
    assert max(steps) <= SLEW_UM_S * 2.0 * PERIOD_S + 1e-3, steps
    assert 0.0 < ramp[1] <= SLEW_UM_S * 2.0 * PERIOD_S + 1e-3
    print(f"foreign 1000.0 µm held ({foreign_at} writes before, offset {before:.2f} µm); "
          f"after clearing: first write {ramp[1]:.3f} µm, max step {max(steps):.3f} µm")


async def _held(rec: RecordingSim) -> bool:
    return bool(await _status(rec) & Status.OFFSET_HELD)


async def _hb_past(rec: RecordingSim, n: float) -> bool:
    return await heartbeat(rec.sim) >= n


async def test_start_up_with_a_foreign_offset_beyond_the_limit_holds(
        rec: RecordingSim, tmp_path: Path) -> None:
    """The controller already holds -1000.0 when `compd run` starts (no
    checkpoint): no offset write until the register is back within the limit."""
    await _foreign_write(int(rec.sim.endpoint.rsplit(":", 1)[1]), -1000.0)
    config = write_config(tmp_path, rec.sim.endpoint, time_scale=TIME_SCALE,
                          slew_um_s=SLEW_UM_S, timeout_s=TIMEOUT_S)
    log = tmp_path / "daemon.log"
    proc = await start_daemon(config, log)
    try:
        await until(lambda: _held(rec), proc, log, "status OFFSET_HELD")
        hb = await heartbeat(rec.sim)
        await until(lambda: _hb_past(rec, hb + 5), proc, log, "heartbeat going on")
        assert rec.offsets == [-1000.0]  # only the foreign write
        await _foreign_write(int(rec.sim.endpoint.rsplit(":", 1)[1]), -90.0)
        await until(lambda: len(rec.writes) > 5, proc, log, "writing again")
        proc.terminate()
        assert await asyncio.wait_for(proc.wait(), 120.0) == 0
    finally:
        await kill_and_wait(proc)
    ramp = rec.offsets[1:]
    assert ramp[0] == -90.0
    steps = [abs(b - a) for a, b in itertools.pairwise(ramp)]
    assert max(steps) <= SLEW_UM_S * 2.0 * PERIOD_S + 1e-3, steps
