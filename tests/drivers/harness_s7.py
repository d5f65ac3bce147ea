"""Contract-test harness for the S7 driver against python-snap7's server."""

from __future__ import annotations

from collections.abc import AsyncIterator, Mapping
from contextlib import asynccontextmanager
from typing import Any

from drivers.addresses import Address, S7Address
from drivers.backoff import Backoff
from drivers.s7 import S7Driver
from drivers.sim.s7_server import S7SimController
from tests.drivers.harness_types import Harness, stall_proxy

PROTOCOL = "s7"


@asynccontextmanager
async def harness() -> AsyncIterator[Harness]:
    sim = S7SimController()
    await sim.start()

    def make_driver(timeout_s: float = 0.5, channels: Mapping[str, Address] | None = None,
                    outputs: Mapping[str, Address] | None = None,
                    endpoint: str | None = None, **options: Any) -> S7Driver:
        options.setdefault("backoff", Backoff(initial_s=0.02, cap_s=0.2))
        return S7Driver(endpoint or sim.endpoint,
                        dict(sim.channels if channels is None else channels),  # type: ignore[arg-type]
                        dict(sim.outputs_map if outputs is None else outputs),  # type: ignore[arg-type]
                        timeout_s=timeout_s, **options)

    async def restart() -> None:
        await sim.stop()
        await sim.forget_outputs()
        await sim.start()

    try:
        async with stall_proxy(sim, make_driver) as stall:
            yield Harness(sim=sim, make_driver=make_driver, stop=sim.stop, restart=restart,
                          bad_address=S7Address(db=99, offset=0, type="REAL"),
                          tolerance=0.001, encodings=dict(sim.encodings),
                          **stall)
    finally:
        await sim.stop()
