"""Errors raised at the driver boundary: every library exception becomes one
of these, carrying the channel and the address it concerns.

"The controller refused" (`WriteRejected`) is kept apart from the daemon's own
refusals (config errors, unusable checkpoints), which derive from
`compd.errors.CompdError`: `DriverError` is the drivers' own base (drivers
never import compd).
"""

from __future__ import annotations


class DriverError(Exception):
    """An I/O failure talking to a controller."""

    def __init__(self, message: str, *, channel: str | None = None,
                 address: str | None = None) -> None:
        self.channel = channel
        self.address = address
        where = ", ".join(
            p for p in (f"channel={channel}" if channel else "",
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

    def __init__(self, message: str, *, channel: str | None = None,
                 address: str | None = None, permanent: bool = False) -> None:
        self.permanent = permanent
        super().__init__(message, channel=channel, address=address)
