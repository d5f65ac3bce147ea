"""Build a driver by protocol name, importing only that protocol's library
(`compd run` must not pay the memory of a driver it does not use). The
protocols are those of `drivers.protocols`."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from drivers.addresses import Address
from drivers.base import Driver
from drivers.protocols import PROTOCOLS, spec_of

#: protocol -> (module, class) of its driver (a view of `drivers.protocols`)
DRIVERS: dict[str, tuple[str, str]] = {
    name: (spec.driver.partition(":")[0], spec.driver.partition(":")[2])
    for name, spec in PROTOCOLS.items()}


def open_driver(protocol: str, endpoint: str, channels: Mapping[str, Address],
                outputs: Mapping[str, Address], **options: Any) -> Driver:
    """Construct (not connect) the driver for `protocol`.

    Every driver takes ``(endpoint, channels, outputs, *, timeout_s=...,
    backoff=None, **protocol_options)``.
    """
    cls = spec_of(protocol).driver_class()
    driver: Driver = cls(endpoint, dict(channels), dict(outputs), **options)
    return driver
