"""Drive maps: where a HIL bench's plant writes its sensors and reads the offset.

On a hardware-in-the-loop bench the simulated plant is a *client* of the real
controller (`drivers.sim.drive`): it writes the temperatures, speed and power
a machine would have into controller addresses the daemon then reads, and
reads back the offset (and heartbeat / status) the daemon wrote. A drive map
(TOML, unknown keys refused) says which addresses those are::

    protocol = "modbus"            # opcua | s7 | modbus | focas
    offset_um_per_unit = 1.0       # µm per engineering unit read at read.offset

    [driver]                       # optional; options of the protocol's driver
    timeout_s = 0.5

    [write]                        # plant channel -> controller address (client-writable)
    bearing = { unit = 1, kind = "holding", address = 20, type = "int16", scale = 0.1 }

    [read]                         # offset (required), heartbeat, status
    offset = { unit = 1, kind = "holding", address = 0, type = "float32" }
    # per axis, the controller's temperature-compensation parameters (optional;
    # `drivers.temp_comp`: µm, µm/m and mm, the scale converting the controller's units)
    x_comp_value = { unit = 1, kind = "holding", address = 34, type = "int32", scale = 0.1 }

Addresses are the typed models of `drivers.addresses` (as in the daemon's
config). Written addresses must be writable by a client (Modbus holding
registers, S7 DBs, FOCAS PMC areas, writable OPC UA nodes) and must not
overlap any other (the plant must never overwrite the daemon's offset); the
rule is the daemon config's, `drivers.footprint.first_clash`.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from drivers.addresses import Address, FocasPmcAddress, ModbusAddress
from drivers.footprint import first_clash
from drivers.protocols import PROTOCOLS, ProtocolName
from drivers.sim import AXIS_OUTPUTS, CHANNELS, OUTPUTS
from drivers.sim.renamed import FORMER_NAMES, current_name, warn_former
from models.nesting import NestingError, loads_toml

#: the protocol names, from the one registry (`drivers.protocols`)
Protocol = ProtocolName

#: the bench maps shipped with the package, one per protocol (`<protocol>.toml`);
#: the repository's deploy/hil/maps points here
MAPS_DIR = Path(__file__).with_name("maps")


def _protocol_options(protocol: str) -> frozenset[str]:
    """Driver options a map may set for `protocol` (besides timeout_s): those
    of its option table (`drivers.protocols`) that `DriverOptions` carries."""
    model = PROTOCOLS[protocol].options_model()
    fields = set(model.model_fields) if model is not None else set()
    return frozenset(fields & set(DriverOptions.model_fields))


class DriveMapError(ValueError):
    """A drive map that cannot be used; the message names the file and key."""


class DriverOptions(BaseModel):
    """Options handed to the protocol's driver (`drivers.factory.open_driver`)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    timeout_s: Annotated[float, Field(gt=0.0, allow_inf_nan=False)] = 0.5
    rack: Annotated[int, Field(ge=0, le=7)] | None = None
    slot: Annotated[int, Field(ge=0, le=31)] | None = None
    library_path: str | None = None
    library_sha256: str | None = None

    def as_kwargs(self) -> dict[str, Any]:
        return self.model_dump(exclude_none=True)


class DriveMap(BaseModel):
    """One validated drive map (see the module docstring)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    protocol: Protocol
    offset_um_per_unit: Annotated[float, Field(allow_inf_nan=False)] = 1.0
    driver: DriverOptions = DriverOptions()
    write: dict[str, Address]
    read: dict[str, Address]

    @model_validator(mode="before")
    @classmethod
    def _typed_addresses(cls, data: Any) -> Any:
        """Validate every address with its protocol's model (clear errors,
        no guessing between protocols)."""
        if not isinstance(data, Mapping) or data.get("protocol") not in PROTOCOLS:
            return data
        spec = PROTOCOLS[data["protocol"]]
        adapter = spec.address_adapter()
        out = dict(data)
        for section in ("write", "read"):
            table = data.get(section)
            if not isinstance(table, Mapping):
                continue
            typed: dict[str, Any] = {}
            for name, given in table.items():
                raw = given
                if spec.default_kind is not None and isinstance(given, Mapping) \
                        and "kind" not in given:
                    raw = {**given, "kind": spec.default_kind}  # as the daemon's config
                try:
                    typed[name] = adapter.validate_python(raw)
                except ValidationError as exc:
                    reasons = "; ".join(
                        f"{'.'.join(str(p) for p in e['loc']) or 'address'}: {e['msg']}"
                        for e in exc.errors())
                    raise ValueError(f"{section}.{name}: not a {data['protocol']} address "
                                     f"({reasons})") from None
            out[section] = typed
        return out

    @model_validator(mode="after")
    def _consistent(self) -> DriveMap:
        if self.offset_um_per_unit == 0.0 or not math.isfinite(self.offset_um_per_unit):
            raise ValueError("offset_um_per_unit must be a finite non-zero number")
        unknown = sorted(set(self.write) - set(CHANNELS))
        if unknown:
            raise ValueError(f"write: unknown plant channel(s) {unknown}; known: {list(CHANNELS)}")
        if not self.write:
            raise ValueError("write: give at least one plant channel")
        unknown = sorted(set(self.read) - set(OUTPUTS) - set(AXIS_OUTPUTS))
        if unknown:
            raise ValueError(f"read: unknown name(s) {unknown}; known: {list(OUTPUTS)} and "
                             "<axis>_comp_value, _slope, _reference for axis x, y, z")
        if "offset" not in self.read:
            raise ValueError("read.offset is required (the address the daemon writes)")
        for name, addr in self.write.items():
            if isinstance(addr, ModbusAddress) and addr.kind != "holding":
                raise ValueError(f"write.{name}: Modbus input registers are read-only for "
                                 "a client; use holding registers")
            if self.protocol == "focas" and not isinstance(addr, FocasPmcAddress):
                raise ValueError(f"write.{name}: only PMC addresses are writable over FOCAS")
        clash = first_clash([
            *(u for n, a in self.write.items() for u in a.uses(f"write.{n}", written=True)),
            *(u for n, a in self.read.items() for u in a.uses(f"read.{n}", written=False))])
        if clash is not None:
            raise ValueError(f"{clash.second.key} {clash.reason()}")
        extra = {k for k in self.driver.as_kwargs() if k != "timeout_s"}
        refused = sorted(extra - _protocol_options(self.protocol))
        if refused:
            raise ValueError(f"driver: option(s) {refused} do not apply to {self.protocol}")
        return self


def parse_drive_map(doc: Mapping[str, Any], source: str = "<map>") -> DriveMap:
    """Validate a parsed TOML document; `DriveMapError` names the key. A plant channel
    under its former name (``speed_rpm``) is taken for its current one, with a
    warning (`drivers.sim.renamed`)."""
    doc = dict(doc)
    write = doc.get("write")
    if isinstance(write, Mapping):
        former = [k for k in write if k in FORMER_NAMES and FORMER_NAMES[k] not in write]
        for old in former:
            warn_former(old, f"{source}: [write]")
        doc["write"] = {current_name(k) if k in former else k: v for k, v in write.items()}
    try:
        return DriveMap.model_validate(doc)
    except ValidationError as exc:
        lines = []
        for e in exc.errors():
            loc = ".".join(str(p) for p in e["loc"])
            msg = str(e["msg"]).removeprefix("Value error, ")
            lines.append(f"{loc}: {msg}" if loc else msg)
        raise DriveMapError(f"{source}: " + "; ".join(lines)) from None


def load_drive_map(path: str | Path) -> DriveMap:
    """Read and validate a drive map file."""
    p = Path(path)
    try:
        doc = loads_toml(p.read_text(encoding="utf-8"))
    except OSError as exc:
        raise DriveMapError(f"{p}: cannot read: {exc.strerror or exc}") from None
    except (tomllib.TOMLDecodeError, NestingError) as exc:
        raise DriveMapError(f"{p}: not valid TOML: {exc}") from None
    return parse_drive_map(doc, str(p))
