"""The shape every protocol's contract-test harness provides.

Each protocol has a module ``tests/drivers/harness_<protocol>.py`` defining
``PROTOCOL: str`` and an async context manager ``harness()`` yielding a
`Harness` whose simulated controller is already started on 127.0.0.1.
`test_contract.py` discovers these modules and runs the same suite on each.
A TCP controller is stalled through a fault proxy in front of it
(`stall_proxy`).
"""

from __future__ import annotations

from collections.abc import AsyncIterator, Awaitable, Callable, Mapping
from contextlib import asynccontextmanager
from dataclasses import dataclass, field
from functools import partial
from typing import Any
from urllib.parse import urlsplit

from drivers.addresses import Address
from drivers.base import Driver
from drivers.sim.base import SimController
from tests.faults.frames import FRAME_LENGTH
from tests.faults.proxy import FaultProxy


@dataclass
class Harness:
    sim: SimController
    #: make_driver(timeout_s=..., channels=None, outputs=None) -> a new, unconnected
    #: driver for the sim's endpoint; None means the sim's own channels/outputs.
    make_driver: Callable[..., Driver]
    #: stop the server (the fast-error test)
    stop: Callable[[], Awaitable[None]]
    #: stop and start the server again on the same endpoint (outputs forgotten)
    restart: Callable[[], Awaitable[None]]
    #: an address valid for the protocol but absent on the server
    bad_address: Address
    #: make_driver's twin whose controller `stall()` can silence
    make_stallable_driver: Callable[..., Driver]
    #: the controller stops answering stallable drivers: their calls time out
    stall: Callable[[], None]
    #: the controller answers again (new connections; a stalled one may stay dead)
    unstall: Callable[[], None]
    #: after the stallable drivers closed: wait until the stall rig holds nothing
    idle: Callable[[], Awaitable[bool]]
    #: largest error the value encoding may introduce (e.g. 0.01 for scale 0.01 ints)
    tolerance: float = 1e-4
    #: extra addresses exercising encodings (word orders, scaled ints, negatives):
    #: name -> address, all also present on the server and writable there
    encodings: Mapping[str, Address] = field(default_factory=dict)


@asynccontextmanager
async def stall_proxy(sim: SimController,
                      make_driver: Callable[..., Driver]) -> AsyncIterator[dict[str, Any]]:
    """The stall fields of a `Harness` for a TCP controller: a fault proxy on
    127.0.0.1 in front of the sim; `make_driver` must take ``endpoint=``."""
    parts = urlsplit(sim.endpoint)
    if parts.hostname is None or parts.port is None:
        raise RuntimeError(f"sim endpoint without host/port: {sim.endpoint}")
    proxy = FaultProxy(parts.hostname, parts.port, frame_length=FRAME_LENGTH[sim.protocol])
    await proxy.start()
    endpoint = parts._replace(netloc=f"{proxy.host}:{proxy.port}").geturl()
    try:
        yield {"make_stallable_driver": partial(make_driver, endpoint=endpoint),
               "stall": proxy.blackhole, "unstall": proxy.pass_through,
               "idle": partial(proxy.wait_idle, 5.0)}
    finally:
        await proxy.stop()
