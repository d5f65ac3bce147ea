"""Configs and a recording driver wrapper for the daemon tests."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

from drivers.base import Driver, Sample

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


class RecordingDriver:
    """Forwards to a real driver and remembers every read-back and write."""

    def __init__(self, inner: Driver) -> None:
        self.inner = inner
        self.protocol = inner.protocol
        #: (offset read back this cycle or None, offset written or None)
        self.cycles: list[tuple[float | None, float | None]] = []
        self._readback: float | None = None

    @property
    def connected(self) -> bool:
        return self.inner.connected

    async def connect(self) -> None:
        await self.inner.connect()

    async def read(self, names: Sequence[str]) -> dict[str, Sample]:
        self._readback = None
        got = await self.inner.read(names)
        if "offset" in got:
            self._readback = got["offset"].value
        return got

    async def write(self, values: Mapping[str, float]) -> None:
        self.cycles.append((self._readback, values.get("offset")))
        await self.inner.write(values)

    async def close(self) -> None:
        await self.inner.close()
