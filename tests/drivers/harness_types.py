"""The shape every protocol's contract-test harness provides.

Each protocol has a module ``tests/drivers/harness_<protocol>.py`` defining
``PROTOCOL: str`` and an async context manager ``harness()`` yielding a
`Harness` whose simulated controller is already started on 127.0.0.1.
`test_contract.py` discovers these modules and runs the same suite on each.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable, Mapping
from dataclasses import dataclass, field

from drivers.addresses import Address
from drivers.base import Driver
from drivers.sim.base import SimController


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
    #: largest error the value encoding may introduce (e.g. 0.01 for scale 0.01 ints)
    tolerance: float = 1e-4
    #: extra addresses exercising encodings (word orders, scaled ints, negatives):
    #: name -> address, all also present on the server and writable there
    encodings: Mapping[str, Address] = field(default_factory=dict)
