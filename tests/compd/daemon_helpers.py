"""Configs for the daemon tests (the recording driver is
`compd.testing.RecordingDriver`), the daemon in lockstep over an in-memory
controller (`memory_daemon`), and a set of simulated Modbus controllers for
the tests of a fleet."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from compd.config.loader import LoadedConfig
    from compd.runtime.daemon import Daemon
    from compd.testing import MemoryDriver, SteppedClock
    from drivers.sim.modbus_server import ModbusSimController

CONFIG = """
[machine]
name = "test"
period_s = 1.0
time_scale = {time_scale}

[controller]
protocol = "modbus"
endpoint = "{endpoint}"
timeout_s = {timeout_s}
connect_timeout_s = 2.0
backoff = {{ initial_s = 0.02, cap_s = 0.2 }}

[channels.bearing]
address = {{ kind = "input", address = 0, type = "int16", scale = 0.1 }}
unit = "degC"
range = [-20.0, 150.0]

[channels.ambient]
address = {{ kind = "input", address = 4, type = "int16", scale = 0.1 }}
unit = "degC"
range = [-10.0, 60.0]

[model]
file = "sp2"

[output]
offset = {{ kind = "holding", address = 0, type = "float32" }}
heartbeat = {{ kind = "holding", address = 2, type = "uint16" }}
status = {{ kind = "holding", address = 3, type = "uint16" }}
limit_um = 100.0
slew_um_s = {slew_um_s}

[faults]
hold_s = 30.0
shutdown = "{shutdown}"

[state]
dir = "state"
checkpoint_every = {checkpoint_every}

[recorder]
commit_every = 10

[telemetry]
log_format = "json"
"""


def write_config(tmp_path: Path, endpoint: str, *, time_scale: float = 50.0,
                 slew_um_s: float = 1.0, shutdown: str = "hold",
                 checkpoint_every: int = 20, timeout_s: float | None = None) -> Path:
    timeout = timeout_s if timeout_s is not None else 0.4 / time_scale
    p = tmp_path / "compd.toml"
    p.write_text(CONFIG.format(endpoint=endpoint, time_scale=time_scale, timeout_s=timeout,
                               slew_um_s=slew_um_s, shutdown=shutdown,
                               checkpoint_every=checkpoint_every), encoding="utf-8")
    return p


async def until(predicate: object, limit: int = 24_000) -> None:
    """Wait (5 ms steps, at most `limit`: 2 min) until `predicate()` is true; the
    bound is generous so that a loaded machine makes a test slower, never red."""
    for _ in range(limit):
        if predicate():  # type: ignore[operator]
            return
        await asyncio.sleep(0.005)
    raise AssertionError("condition not reached")


async def pace(clock: SteppedClock) -> None:
    """Each time the daemon sleeps on `clock`, move the clock to its next deadline:
    its cycles follow each other as fast as the machine allows, one period apart
    on its clock (a task the test cancels once the daemon has stopped)."""
    while True:
        await clock.cycle_done(clock.ticks + 1)
        clock.tick()


@contextlib.asynccontextmanager
async def modbus_sims(count: int) -> AsyncIterator[list[ModbusSimController]]:
    """`count` simulated Modbus controllers on free 127.0.0.1 ports, bearing and
    ambient at 20 °C, stopped on exit."""
    from drivers.sim.modbus_server import ModbusSimController

    controllers = [ModbusSimController() for _ in range(count)]
    for c in controllers:
        await c.start()
        await c.publish({"bearing": 20.0, "ambient": 20.0})
    try:
        yield controllers
    finally:
        for c in controllers:
            await c.stop()


def memory_daemon(cfg: LoadedConfig, *, epoch: float | None = None,
                  **daemon_args: Any) -> tuple[Daemon, SteppedClock, MemoryDriver]:
    """The real daemon in-process over an in-memory controller (bearing and
    ambient at 20 °C; offset, heartbeat and status written), driven by one
    `SteppedClock`: a cycle per `clock.tick()`, awaited with `clock.cycle_done`.
    `epoch`: the wall clock's reading at the stepped clock's 0, for the driver's
    sample stamps and the daemon (None: the daemon's own wall clock)."""
    from compd.runtime.daemon import Daemon
    from compd.runtime.sdnotify import Notifier
    from compd.testing import MemoryDriver, SteppedClock

    clock = SteppedClock(period_s=cfg.period_s)
    stamped: dict[str, Any] = {}
    if epoch is not None:
        start = epoch

        def wall() -> float:
            return start + clock()

        stamped["wall"] = wall
    driver = MemoryDriver({"bearing": 20.0, "ambient": 20.0},
                          ("offset", "heartbeat", "status"), **stamped)
    daemon = Daemon(cfg, driver=driver, notifier=Notifier(None), clock=clock,
                    sleep=clock.sleep, **stamped, **daemon_args)
    return daemon, clock, driver
