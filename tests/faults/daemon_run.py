"""`compd run` as a subprocess against a simulated Modbus controller that
records every offset write (value and time), for the kill -9, second
instance and disk-full tests."""

from __future__ import annotations

import asyncio
import itertools
import os
import sys
import time
from pathlib import Path
from typing import Any

from drivers.modbus_codec import decode
from drivers.sim.modbus_server import OUTPUTS, ModbusSimController

ROOT = Path(__file__).resolve().parents[2]


class RecordingSim:
    """A Modbus sim that remembers every offset written: (monotonic s, µm)."""

    def __init__(self) -> None:
        self.sim = ModbusSimController()
        self.writes: list[tuple[float, float]] = []
        #: index into `writes` where each daemon run starts (set by the test)
        self.run_starts: list[int] = []
        original = self.sim._action

        async def action(function_code: int, start: int, address: int, count: int,
                         registers: list[int], set_values: Any) -> Any:
            if set_values is not None and address == 0 and count >= 2:
                self.writes.append((time.monotonic(),
                                    decode(OUTPUTS["offset"], list(set_values[:2]))))
            return await original(function_code, start, address, count, registers,
                                  set_values)

        self.sim._action = action  # type: ignore[method-assign,assignment]  # watch writes

    @property
    def offsets(self) -> list[float]:
        return [v for _, v in self.writes]

    async def start(self) -> None:
        await self.sim.start()
        await self.sim.publish({"bearing": 20.0, "ambient": 20.0})

    async def stop(self) -> None:
        await self.sim.stop()


def daemon_env() -> dict[str, str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("NOTIFY_SOCKET", None)
    return env


async def start_daemon(config: Path, stderr_path: Path) -> asyncio.subprocess.Process:
    """`compd run CONFIG` with stderr appended to `stderr_path`."""
    with stderr_path.open("ab") as f:
        return await asyncio.create_subprocess_exec(
            sys.executable, "-m", "compd", "run", str(config),
            stdin=asyncio.subprocess.DEVNULL, stdout=f, stderr=f, env=daemon_env(),
            cwd=str(ROOT))


async def heartbeat(sim: ModbusSimController) -> float:
    return (await sim.outputs())["heartbeat"]


async def kill_and_wait(proc: asyncio.subprocess.Process) -> None:
    if proc.returncode is None:
        proc.kill()
    await proc.wait()


def max_step(offsets: list[float]) -> float:
    return max((abs(b - a) for a, b in itertools.pairwise(offsets)), default=0.0)


def forget_daemon_logging() -> None:
    """Undo what an in-process `compd run` did to logging (`configure_logging`
    binds structlog and a root handler to the stderr of that moment)."""
    import logging

    import structlog

    root = logging.getLogger()
    for handler in [h for h in root.handlers if h.get_name() == "compd"]:
        root.removeHandler(handler)
    structlog.reset_defaults()
