"""The daemon's own refusals ("we refused"), kept apart from the controller's
(`drivers.errors.WriteRejected`). All derive from the one root `CompdError`."""

from __future__ import annotations

from compd.sysexits import EX_CONFIG  # systemd is told not to restart on it
from models.errors import CompdError, ModelError

__all__ = ["EX_CONFIG", "CompdError", "ConfigError", "ModelError", "SafetyTrip"]



class ConfigError(CompdError):
    """The configuration is invalid. `key` is the dotted key path, `reason` why."""

    def __init__(self, key: str, reason: str) -> None:
        self.key = key
        self.reason = reason
        super().__init__(f"{key}: {reason}" if key else reason)


class SafetyTrip(CompdError):
    """The daemon stopped compensating on purpose (a permanent write refusal,
    a state it cannot trust)."""
