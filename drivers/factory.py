"""Build a driver by protocol name, importing only that protocol's library
(`compd run` must not pay the memory of a driver it does not use)."""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from typing import Any

from drivers.addresses import Address
from drivers.base import Driver

#: protocol -> (module, class)
DRIVERS: dict[str, tuple[str, str]] = {
    "opcua": ("drivers.opcua", "OpcUaDriver"),
    "s7": ("drivers.s7", "S7Driver"),
    "modbus": ("drivers.modbus", "ModbusDriver"),
    "focas": ("drivers.focas", "FocasDriver"),
}


def open_driver(protocol: str, endpoint: str, channels: Mapping[str, Address],
                outputs: Mapping[str, Address], **options: Any) -> Driver:
    """Construct (not connect) the driver for `protocol`.

    Every driver takes ``(endpoint, channels, outputs, *, timeout_s=...,
    backoff=None, **protocol_options)``.
    """
    try:
        module_name, class_name = DRIVERS[protocol]
    except KeyError:
        raise ValueError(f"unknown protocol {protocol!r}; known: {sorted(DRIVERS)}") from None
    cls = getattr(importlib.import_module(module_name), class_name)
    driver: Driver = cls(endpoint, dict(channels), dict(outputs), **options)
    return driver
