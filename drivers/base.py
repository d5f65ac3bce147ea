"""The one async interface every protocol driver implements.

A driver is constructed with its endpoint and the named addresses it may
touch: `channels` (inputs it reads) and `outputs` (what it writes: the offset,
a heartbeat counter, a status word; outputs can be read back too). Names are
the daemon's channel names; addresses are the typed models of
`drivers.addresses`.

Rules every implementation keeps:
- every library exception is turned into a `drivers.errors.DriverError`
  subclass carrying the channel and the address;
- every call has a timeout well under the sample period and never blocks the
  event loop (blocking libraries run in a worker thread);
- reconnect with capped exponential backoff (`drivers.backoff.Backoff`) is the
  driver's job, done the same way by all through `drivers.link.Link`: on a
  lost link or a timeout `read`/`write` fail fast with `ConnectionLost` and
  the next call after the backoff delay tries to reconnect; after `close()`
  they fail until `connect()`;
- writes are never retried at transport level (a write is not idempotent for
  the controller's ladder logic).
"""

from __future__ import annotations

import enum
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol, TypeVar, runtime_checkable

from drivers.errors import BadAddress


class Quality(enum.Enum):
    """Per-value quality as the controller reported it."""

    GOOD = "good"
    UNCERTAIN = "uncertain"
    BAD = "bad"


@dataclass(frozen=True, slots=True)
class Sample:
    """One channel value read from the controller.

    `timestamp_s` is the source timestamp when the protocol supplies one, else
    the wall-clock time of the read (seconds since the epoch).
    """

    value: float
    timestamp_s: float
    quality: Quality = Quality.GOOD


@runtime_checkable
class Driver(Protocol):
    """Async access to one controller."""

    protocol: str

    @property
    def connected(self) -> bool:
        """True while the link is believed to be up."""
        ...

    async def connect(self) -> None:
        """Open the link; raise `ConnectionLost`/`ControllerTimeout` on failure."""
        ...

    async def read(self, names: Sequence[str]) -> dict[str, Sample]:
        """Read the named channels (or outputs) in as few requests as the
        protocol allows. Unknown names raise `BadAddress`."""
        ...

    async def write(self, values: Mapping[str, float]) -> None:
        """Write the named outputs (offset, heartbeat, status word) with the
        type each address declares. Unknown names raise `BadAddress`."""
        ...

    async def close(self) -> None:
        """Release the link and any worker thread; idempotent."""
        ...


A = TypeVar("A")


def select_addresses(names: Sequence[str], table: Mapping[str, A], kind: str) -> dict[str, A]:
    """The addresses of `names` from a driver's `table` (its channels or its
    outputs); an unknown name raises `BadAddress` naming it."""
    missing = [name for name in names if name not in table]
    if missing:
        raise BadAddress(f"unknown {kind} {missing[0]!r}", channel=missing[0])
    return {name: table[name] for name in names}
