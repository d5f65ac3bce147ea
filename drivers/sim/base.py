"""What every simulated controller offers to the plant and to tests."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Protocol

from drivers.addresses import Address


class SimController(Protocol):
    """A real protocol server on 127.0.0.1 standing in for a controller.

    The plant side calls `publish` with sensor values and reads back what the
    daemon wrote with `outputs`; `forget_outputs` models a controller restart
    that loses the offset.
    """

    protocol: str
    #: e.g. "opc.tcp://127.0.0.1:4840", "modbus://127.0.0.1:5020"
    endpoint: str
    channels: dict[str, Address]
    outputs_map: dict[str, Address]
    #: the measuring cycle's addresses (`drivers.sim.PROBES`)
    probes: dict[str, Address]

    async def start(self) -> None: ...

    async def stop(self) -> None: ...

    async def publish(self, values: Mapping[str, float]) -> None: ...

    async def outputs(self) -> dict[str, float]: ...

    async def forget_outputs(self) -> None: ...
