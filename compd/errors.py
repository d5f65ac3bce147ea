"""The daemon's own refusals ("we refused"): the root `CompdError` and the
configuration's `ConfigError`.

The root lives here, in the package that composes the others. The layers
below keep bases of their own, since they may not import compd: the numeric
core's `models.errors.ModelError` (a model malformed or unsafe) and the
drivers' `drivers.errors.DriverError` ("the controller refused", a lost
link), which stay apart from compd's refusals as the design asks.
"""

from __future__ import annotations

from compd.sysexits import EX_CONFIG  # systemd is told not to restart on it

__all__ = ["EX_CONFIG", "CompdError", "ConfigError"]


class CompdError(Exception):
    """Root of every error the daemon and its commands raise on purpose."""


class ConfigError(CompdError):
    """The configuration is invalid. `key` is the dotted key path, `reason` why."""

    def __init__(self, key: str, reason: str) -> None:
        self.key = key
        self.reason = reason
        super().__init__(f"{key}: {reason}" if key else reason)
