"""Contract-test harness for the FOCAS driver against the stand-in library."""

from __future__ import annotations

from collections.abc import AsyncIterator, Mapping
from contextlib import asynccontextmanager
from typing import Any

from drivers.addresses import Address, FocasPmcAddress
from drivers.backoff import Backoff
from drivers.focas import FocasDriver
from drivers.sim.focas_server import FocasSimController
from tests.drivers.harness_types import Harness

PROTOCOL = "focas"
#: a stalled stand-in library takes this long per call (longer than any
#: contract test's timeout plus the worker grace)
STALL_US = 1_500_000


@asynccontextmanager
async def harness() -> AsyncIterator[Harness]:
    sim = FocasSimController()
    await sim.start()

    def make_driver(timeout_s: float = 0.5, channels: Mapping[str, Address] | None = None,
                    outputs: Mapping[str, Address] | None = None,
                    **options: Any) -> FocasDriver:
        options.setdefault("backoff", Backoff(initial_s=0.02, cap_s=0.2))
        options.setdefault("library_path", sim.library_path)
        return FocasDriver(sim.endpoint,
                           dict(sim.channels if channels is None else channels),  # type: ignore[arg-type]
                           dict(sim.outputs_map if outputs is None else outputs),  # type: ignore[arg-type]
                           timeout_s=timeout_s, **options)

    async def restart() -> None:
        await sim.stop()
        await sim.forget_outputs()
        await sim.start()

    async def idle() -> bool:
        return True  # no connection to wait for: the library is in-process

    try:
        yield Harness(sim=sim, make_driver=make_driver, stop=sim.stop, restart=restart,
                      bad_address=FocasPmcAddress(area="D", address=60000, type="long"),
                      make_stallable_driver=make_driver,
                      stall=lambda: sim.set_latency_us(STALL_US),
                      unstall=lambda: sim.set_latency_us(0), idle=idle,
                      tolerance=0.05, encodings=dict(sim.encodings))  # offset long ×0.1 µm
    finally:
        await sim.stop()
        sim.close()
