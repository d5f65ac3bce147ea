"""Build a simulated controller by protocol name (lazy imports)."""

from __future__ import annotations

import importlib
from typing import Any

from drivers.sim.base import SimController

#: protocol -> (module, class); each class takes (host="127.0.0.1", port=0, **options)
SIM_CONTROLLERS: dict[str, tuple[str, str]] = {
    "opcua": ("drivers.sim.opcua_server", "OpcUaSimController"),
    "s7": ("drivers.sim.s7_server", "S7SimController"),
    "modbus": ("drivers.sim.modbus_server", "ModbusSimController"),
    "focas": ("drivers.sim.focas_server", "FocasSimController"),
}


def make_sim_controller(protocol: str, host: str = "127.0.0.1", port: int = 0,
                        **options: Any) -> SimController:
    try:
        module_name, class_name = SIM_CONTROLLERS[protocol]
    except KeyError:
        raise ValueError(
            f"unknown protocol {protocol!r}; known: {sorted(SIM_CONTROLLERS)}") from None
    cls = getattr(importlib.import_module(module_name), class_name)
    controller: SimController = cls(host=host, port=port, **options)
    return controller
