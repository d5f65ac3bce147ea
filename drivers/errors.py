"""Errors raised at the driver boundary: every library exception becomes one
of these, carrying the channel(s) and the address it concerns.

`channels` is a tuple of names: one for a single channel, every name of a
combined read or write (a Modbus span, an OPC UA Read of several nodes), ()
when the error concerns no channel in particular. Callers pass one name as a
string or several as a sequence (`Channels`); nothing joins names into one
string that a reader would have to split (the daemon counts a failed write
per output, a Prometheus label each).

"The controller refused" (`WriteRejected`) is kept apart from the daemon's own
refusals (config errors, unusable checkpoints), which derive from
`compd.errors.CompdError`: `DriverError` is the drivers' own base (drivers
never import compd).
"""

from __future__ import annotations

from collections.abc import Sequence

__all__ = ["BadAddress", "Channels", "ConnectionLost", "ControllerTimeout", "DriverError",
           "WriteRejected", "channel_names"]

#: one channel's name, several names, or None
Channels = str | Sequence[str] | None


def channel_names(channel: Channels) -> tuple[str, ...]:
    """`Channels` as a tuple of names (a string is one name, never split)."""
    if channel is None:
        return ()
    if isinstance(channel, str):
        return (channel,) if channel else ()
    return tuple(channel)


class DriverError(Exception):
    """An I/O failure talking to a controller."""

    def __init__(self, message: str, *, channel: Channels = None,
                 address: str | None = None) -> None:
        self.channels = channel_names(channel)
        self.address = address
        where = ", ".join(
            p for p in (f"channel={','.join(self.channels)}" if self.channels else "",
                        f"address={address}" if address else "") if p
        )
        super().__init__(f"{message} ({where})" if where else message)


class ControllerTimeout(DriverError, TimeoutError):
    """A request did not complete within its timeout (also a `TimeoutError`,
    so code that bounds a call with `asyncio.timeout` handles both alike)."""


class ConnectionLost(DriverError):
    """The link to the controller is down (or was never up); the call failed fast."""


class BadAddress(DriverError):
    """The address does not exist on the controller or cannot be encoded."""


class WriteRejected(DriverError):
    """The controller answered a write with a refusal.

    `permanent` is True when retrying cannot help (not writable, access denied,
    wrong type); False for a transient refusal (busy, device failure).
    """

    def __init__(self, message: str, *, channel: Channels = None,
                 address: str | None = None, permanent: bool = False) -> None:
        self.permanent = permanent
        super().__init__(message, channel=channel, address=address)
