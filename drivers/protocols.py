"""Every protocol compd speaks, described once and found by name here.

A `ProtocolSpec` says, for one protocol: its address model(s), the table of
its options under ``[controller]`` in the daemon's config (and in a HIL drive
map's ``[driver]``), its driver and its simulated controller. The daemon's
config, `drivers.factory`, the simulated controllers (`drivers.sim`) and the
command line all look protocols up here; a new protocol joins by adding its
spec.

Nothing here imports a protocol library, pydantic or the address models:
each part is named ``"module:attribute"`` and imported on use, so building
the command line stays light and ``compd run`` loads only the driver it uses.
"""

from __future__ import annotations

import functools
import importlib
import operator
from dataclasses import dataclass
from typing import Annotated, Any, Literal, get_args

#: the protocol names (a Literal for the config and drive-map models)
ProtocolName = Literal["opcua", "s7", "modbus", "focas", "linuxcnc"]
NAMES: tuple[str, ...] = get_args(ProtocolName)


_ADAPTERS: dict[str, Any] = {}


def _resolve(ref: str) -> Any:
    module, _, attr = ref.partition(":")
    return getattr(importlib.import_module(module), attr)


@dataclass(frozen=True, slots=True)
class ProtocolSpec:
    """One protocol's parts (see the module docstring)."""

    name: str
    #: the URL scheme of the driver's endpoint (``opc.tcp://``, ``s7://``, ...)
    scheme: str
    #: the address models a channel or output may use ("module:Class")
    addresses: tuple[str, ...]
    #: the driver class; constructed as ``cls(endpoint, channels, outputs, **options)``
    driver: str
    #: the simulated controller class; ``cls(host="127.0.0.1", port=0, **options)``
    sim: str
    #: the ``[controller.<section>]`` table of its options (None: it has none)
    section: str | None = None
    #: the model of that table ("module:Class")
    options: str | None = None
    #: why the table must be given, when it must (None: it is optional)
    section_required: str | None = None
    #: the address ``kind`` assumed when an address table gives none
    default_kind: str | None = None
    #: the driver takes ``connect_timeout_s`` (a connect slower than a request)
    connect_timeout: bool = False
    #: the endpoint (`drivers.endpoint`): the protocol's name in messages, its
    #: port when the URL gives none, whether it has a path, other schemes it
    #: answers to, and whether a bare ``host:port`` is one
    title: str = ""
    default_port: int = 0
    endpoint_path: bool = False
    scheme_aliases: tuple[str, ...] = ()
    bare_host_port: bool = False
    #: the controller is on this machine only (LinuxCNC's HAL is shared memory)
    local_only: bool = False

    @property
    def endpoint_form(self) -> str:
        """The endpoint's shape, for messages: ``'s7://host[:102]'``."""
        path = "[/path]" if self.endpoint_path else ""
        bare = f" or 'host[:{self.default_port}]'" if self.bare_host_port else ""
        return f"'{self.scheme}://host[:{self.default_port}]{path}'{bare}"

    def address_types(self) -> tuple[type[Any], ...]:
        return tuple(_resolve(ref) for ref in self.addresses)

    def address_adapter(self) -> Any:
        """A pydantic ``TypeAdapter`` for one address of this protocol (several
        models are told apart by their ``kind``); built once."""
        adapter = _ADAPTERS.get(self.name)
        if adapter is None:
            from pydantic import Field, TypeAdapter

            types = self.address_types()
            target: Any = types[0] if len(types) == 1 else Annotated[
                functools.reduce(operator.or_, types), Field(discriminator="kind")]
            adapter = _ADAPTERS[self.name] = TypeAdapter(target)
        return adapter

    def options_model(self) -> type[Any] | None:
        return None if self.options is None else _resolve(self.options)

    def driver_class(self) -> type[Any]:
        cls: type[Any] = _resolve(self.driver)
        return cls

    def sim_class(self) -> type[Any]:
        cls: type[Any] = _resolve(self.sim)
        return cls


PROTOCOLS: dict[str, ProtocolSpec] = {spec.name: spec for spec in (
    ProtocolSpec(
        "opcua", "opc.tcp", ("drivers.addresses:OpcUaAddress",), "drivers.opcua:OpcUaDriver",
        "drivers.sim.opcua_server:OpcUaSimController", section="security",
        options="drivers.opcua_policy:OpcUaSecurityRules",
        section_required='a policy, or policy = "None" with insecure = true',
        connect_timeout=True, title="OPC UA", default_port=4840, endpoint_path=True),
    ProtocolSpec(
        "s7", "s7", ("drivers.addresses:S7Address",), "drivers.s7:S7Driver",
        "drivers.sim.s7_server:S7SimController", section="s7",
        options="drivers.protocol_options:S7Options", title="S7", default_port=102),
    ProtocolSpec(
        "modbus", "modbus", ("drivers.addresses:ModbusAddress",), "drivers.modbus:ModbusDriver",
        "drivers.sim.modbus_server:ModbusSimController", title="Modbus TCP", default_port=502,
        scheme_aliases=("modbus+tcp", "tcp"), bare_host_port=True),
    ProtocolSpec(
        "focas", "focas",
        ("drivers.addresses:FocasPmcAddress", "drivers.addresses:FocasDiagAddress",
         "drivers.addresses:FocasSpindleLoadAddress"),
        "drivers.focas:FocasDriver", "drivers.sim.focas_server:FocasSimController",
        section="focas", options="drivers.protocol_options:FocasOptions",
        section_required="library_path", default_kind="pmc", title="FOCAS",
        default_port=8193),
    ProtocolSpec(
        "linuxcnc", "linuxcnc",
        ("drivers.addresses:LinuxCncPin", "drivers.addresses:LinuxCncEoffset",
         "drivers.addresses:LinuxCncGet"),
        "drivers.linuxcnc:LinuxCncDriver", "drivers.sim.linuxcnc_machine:LinuxCncSimController",
        section="linuxcnc", options="drivers.linuxcnc_options:LinuxCncOptions",
        default_kind="pin", connect_timeout=True, title="LinuxCNC HAL", default_port=0,
        local_only=True),
)}


def spec_of(name: str) -> ProtocolSpec:
    """The spec of `name`; `ValueError` naming the known ones otherwise."""
    try:
        return PROTOCOLS[name]
    except KeyError:
        raise ValueError(f"unknown protocol {name!r}; known: {sorted(PROTOCOLS)}") from None


assert set(NAMES) == set(PROTOCOLS), "ProtocolName and PROTOCOLS disagree"

__all__ = ["NAMES", "PROTOCOLS", "ProtocolName", "ProtocolSpec", "spec_of"]
