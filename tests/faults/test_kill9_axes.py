"""Random kill -9 of `compd run` writing Z's offset and X's offset at X's position at
once (the simulated Modbus controller, X written as one offset register at the
position read each cycle, `[output.axes.x] position`), over and over, the
temperatures changed at random between runs so that both targets keep moving.

Checked over every write that reaches the controller, across all the restarts: Z's
offset moves by at most its slew over two periods, and X's by at most its value's
slew plus its slope's slew at X's distance from the reference, over two periods (X
stands still, so no motion adds to it; a restart's first step capped at two periods
of slew like any other, which an axis capped at six periods fails). The checkpoint
loads after every kill."""

from __future__ import annotations

import asyncio
import itertools
import random
from pathlib import Path
from typing import Any

from compd.runtime.checkpoint import load_checkpoint
from drivers.modbus_codec import decode
from drivers.sim.modbus_server import AXIS_OFFSETS, OUTPUTS, ModbusSimController
from tests.compd.axes_helpers import SENSOR_CHANNELS
from tests.compd.runtime.test_axes_position_modbus import positional_config_text
from tests.faults.daemon_run import heartbeat, kill_and_wait, start_daemon
from tests.harness import tail, until

PERIOD_S, TIME_SCALE = 1.0, 20.0
Z_SLEW, X_SLEW, SLOPE_SLEW = 1.0, 1.0, 1.0  # µm/s, µm/s, µm/m per s
X_MM = 400.0  # where X stands, from the reference at 0 mm
KILLS = 8
#: float32 registers: a written value is within this of the one planned
F32_UM = 1e-4


class TwoAxisRecorder:
    """The Modbus sim, remembering every Z and X offset written (in order)."""

    def __init__(self) -> None:
        self.sim = ModbusSimController()
        self.z: list[float] = []
        self.x: list[float] = []
        x_addr = next(a for n, a in AXIS_OFFSETS.items() if n.startswith("x_"))
        z_addr = OUTPUTS["offset"]
        original = self.sim._action

        async def action(function_code: int, start: int, address: int, count: int,
                         registers: list[int], set_values: Any) -> Any:
            if set_values is not None:
                regs = list(set_values)
                for addr, seen in ((z_addr, self.z), (x_addr, self.x)):
                    at = addr.address - address
                    if at >= 0 and at + 2 <= count:
                        seen.append(decode(addr, regs[at:at + 2]))
            return await original(function_code, start, address, count, registers,
                                  set_values)

        self.sim._action = action  # type: ignore[method-assign,assignment]  # watch writes


def _temperatures(rng: random.Random) -> dict[str, float]:
    return {SENSOR_CHANNELS["column"]: rng.uniform(20.0, 26.0),
            SENSOR_CHANNELS["screw_bearing"]: rng.uniform(20.0, 26.0),
            SENSOR_CHANNELS["nut"]: rng.uniform(20.0, 28.0),
            SENSOR_CHANNELS["ambient"]: 20.0}


async def test_random_kill9_with_x_at_its_position_and_z_never_jumps(tmp_path: Path) -> None:
    rng = random.Random(33)
    rec = TwoAxisRecorder()
    await rec.sim.start()
    try:
        await rec.sim.publish({**_temperatures(rng), "x_position": X_MM})
        config = tmp_path / "compd.toml"
        config.write_text(positional_config_text(
            rec.sim.endpoint, period_s=PERIOD_S, time_scale=TIME_SCALE,
            timeout_s=0.5 * PERIOD_S / TIME_SCALE, value_slew=X_SLEW, slope_slew=SLOPE_SLEW),
            encoding="utf-8")
        # Z: 3 µm/K of the column from 20 °C, so that its target moves as X's does
        text = config.read_text(encoding="utf-8")
        z_term = '[model]\n[[model.terms]]\nname = "column"\ninputs = { column = 1.0 }'
        assert z_term in text
        text = text.replace(z_term, "[model]\nreference = { column = 20.0 }\n"
                            + z_term.removeprefix("[model]\n").replace("1.0", "3.0"), 1)
        config.write_text(text.replace("slew_um_s = 1.0\n", f"slew_um_s = {Z_SLEW}\n", 1),
                          encoding="utf-8")
        log = tmp_path / "daemon.log"
        checkpoint = tmp_path / "state" / "checkpoint.json"
        for i in range(KILLS):
            await rec.sim.publish(_temperatures(rng))
            proc = await start_daemon(config, log)
            try:
                if i % 2:  # half the kills land after a write, half anywhere
                    n = len(rec.x)
                    await until(lambda n=n: len(rec.x) > n, proc, log, f"run {i} writing X")
                await asyncio.sleep(rng.uniform(0.0, 0.5))
            finally:
                await kill_and_wait(proc)
            load_checkpoint(checkpoint)  # CheckpointError here is a torn state file
        # a last run that ends cleanly, long enough that both offsets settle a while
        proc = await start_daemon(config, log)
        try:
            hb = await heartbeat(rec.sim)
            await until(lambda: _hb_past(rec.sim, hb + 20), proc, log, "final run cycling")
            proc.terminate()
            assert await asyncio.wait_for(proc.wait(), 120.0) == 0, await asyncio.to_thread(
                tail, log)
        finally:
            await kill_and_wait(proc)
    finally:
        await rec.sim.stop()

    z_bound = Z_SLEW * 2 * PERIOD_S + F32_UM
    x_bound = (X_SLEW + SLOPE_SLEW * X_MM / 1000.0) * 2 * PERIOD_S + F32_UM
    z_steps = [abs(b - a) for a, b in itertools.pairwise(rec.z)]
    x_steps = [abs(b - a) for a, b in itertools.pairwise(rec.x)]
    assert x_steps and z_steps
    assert max(z_steps) <= z_bound, (max(z_steps), z_bound)
    assert max(x_steps) <= x_bound, (max(x_steps), x_bound)
    # both really moved meanwhile, so the bounds were tested against moving targets
    assert max(rec.x) - min(rec.x) > 3 * x_bound
    assert max(rec.z) - min(rec.z) > 3 * z_bound
    state = load_checkpoint(checkpoint)
    assert state is not None
    print(f"kill9 X+Z: {KILLS} kills, {len(rec.x)} X writes (max step "
          f"{max(x_steps):.3f} of {x_bound:.3f} µm, range {min(rec.x):.2f}..{max(rec.x):.2f}), "
          f"{len(rec.z)} Z writes (max step {max(z_steps):.3f} of {z_bound:.3f} µm)")


async def _hb_past(sim: ModbusSimController, n: float) -> bool:
    return await heartbeat(sim) >= n
