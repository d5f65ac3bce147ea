"""Contract-test harness for Modbus TCP: the pymodbus simulated controller
on a free loopback port and `ModbusDriver` pointed at it."""

from __future__ import annotations

from collections.abc import AsyncIterator, Mapping
from contextlib import asynccontextmanager
from typing import Any

from drivers.addresses import Address
from drivers.backoff import Backoff
from drivers.modbus import ModbusDriver
from drivers.sim.modbus_server import BAD_ADDRESS, ENCODINGS, ModbusSimController
from tests.drivers.harness_types import Harness, stall_proxy

PROTOCOL = "modbus"


@asynccontextmanager
async def harness() -> AsyncIterator[Harness]:
    sim = ModbusSimController()
    await sim.start()

    def make_driver(timeout_s: float = 0.5, channels: Mapping[str, Address] | None = None,
                    outputs: Mapping[str, Address] | None = None,
                    endpoint: str | None = None, **options: Any) -> ModbusDriver:
        options.setdefault("backoff", Backoff(initial_s=0.02, cap_s=0.2))
        return ModbusDriver(endpoint or sim.endpoint,
            dict(sim.channels if channels is None else channels),
            dict(sim.outputs_map if outputs is None else outputs),
            timeout_s=timeout_s, **options)

    async def restart() -> None:
        await sim.stop()
        await sim.forget_outputs()
        await sim.start()

    try:
        async with stall_proxy(sim, make_driver) as stall:
            yield Harness(sim=sim, make_driver=make_driver, stop=sim.stop, restart=restart,
                          bad_address=BAD_ADDRESS, tolerance=1e-3, encodings=dict(ENCODINGS),
                          **stall)
    finally:
        await sim.stop()
