"""Contract-test harness for OPC UA: the asyncua simulated controller on a
free loopback port and `OpcUaDriver` pointed at it."""

from __future__ import annotations

from collections.abc import AsyncIterator, Mapping
from contextlib import asynccontextmanager
from typing import Any

from drivers.addresses import Address, OpcUaAddress
from drivers.backoff import Backoff
from drivers.opcua import OpcUaDriver
from drivers.sim.opcua_server import NAMESPACE_INDEX, OpcUaSimController
from tests.drivers.harness_types import Harness, stall_proxy

PROTOCOL = "opcua"

#: a well-formed NodeId in the sim's namespace that the server does not have
BAD_ADDRESS = OpcUaAddress(node=f"ns={NAMESPACE_INDEX};s=Machine.NoSuchNode")


@asynccontextmanager
async def harness(**sim_options: Any) -> AsyncIterator[Harness]:
    sim = OpcUaSimController(**sim_options)
    await sim.start()

    def make_driver(timeout_s: float = 0.5, channels: Mapping[str, Address] | None = None,
                    outputs: Mapping[str, Address] | None = None,
                    endpoint: str | None = None, **options: Any) -> OpcUaDriver:
        options.setdefault("backoff", Backoff(initial_s=0.02, cap_s=0.2))
        return OpcUaDriver(
            endpoint or sim.endpoint,
            dict(sim.channels if channels is None else channels),  # type: ignore[arg-type]
            dict(sim.outputs_map if outputs is None else outputs),  # type: ignore[arg-type]
            timeout_s=timeout_s, **options)

    try:
        async with stall_proxy(sim, make_driver) as stall:
            yield Harness(sim=sim, make_driver=make_driver, stop=sim.stop, restart=sim.restart,
                          bad_address=BAD_ADDRESS, tolerance=1e-4, encodings=dict(sim.encodings),
                          **stall)
    finally:
        await sim.stop()
