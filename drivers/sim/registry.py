"""Build a simulated controller by protocol name (lazy imports; the
protocols are those of `drivers.protocols`)."""

from __future__ import annotations

from typing import Any

from drivers.protocols import PROTOCOLS, spec_of
from drivers.sim.base import SimController

#: protocol -> (module, class); each class takes (host="127.0.0.1", port=0, **options)
SIM_CONTROLLERS: dict[str, tuple[str, str]] = {
    name: (spec.sim.partition(":")[0], spec.sim.partition(":")[2])
    for name, spec in PROTOCOLS.items()}


def make_sim_controller(protocol: str, host: str = "127.0.0.1", port: int = 0,
                        **options: Any) -> SimController:
    cls = spec_of(protocol).sim_class()
    controller: SimController = cls(host=host, port=port, **options)
    return controller
