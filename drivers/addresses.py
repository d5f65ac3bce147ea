"""Typed, validated addresses per protocol (pydantic models).

Each address model is what one channel or output looks like in the daemon's
config and in `compd sim --json`. Unknown keys are refused. `describe()`
gives the short string used in error messages and logs; `encoding` and
`raw_range` the raw encoding (`drivers.encodings`; None for an OPC UA node,
typed by its server, and for FOCAS calls that are not PMC memory);
`footprint()` the controller memory it occupies (`drivers.footprint`), which
the codecs write and the config check keeps apart.
"""

from __future__ import annotations

import math
import re
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from drivers.encodings import HAL_TYPES, MODBUS_TYPES, PMC_ENCODINGS, S7_TYPES, Encoding
from drivers.footprint import Footprint, Use


class _Address(BaseModel):
    # strict: a register number written as "5" or a scale as "0.1" is a config
    # mistake to report, not to guess at (ints are still accepted for floats)
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)

    def describe(self) -> str:
        raise NotImplementedError

    @property
    def encoding(self) -> Encoding | None:
        """The raw encoding of the value (None: not known from the address)."""
        return None

    @property
    def raw_range(self) -> tuple[int | float, int | float] | None:
        """The raw values the encoding holds (engineering value = raw * scale)."""
        enc = self.encoding
        return None if enc is None else enc.range

    def footprint(self) -> Footprint | None:
        """The controller memory this address occupies (None: none a client writes)."""
        return None

    def use(self, key: str, *, written: bool) -> Use:
        """This address as `key` uses it, for `drivers.footprint.first_clash`: two
        reads of it that differ only in their scale read the same value."""
        fields = self.model_dump(exclude={"scale", "node"})
        return Use(key, self.footprint(), written, tuple(sorted(fields.items())))

    def uses(self, key: str, *, written: bool) -> tuple[Use, ...]:
        """Every use of controller resources by this address: one (`use`), but a
        LinuxCNC pin is both compd's pin and the HAL signal it joins."""
        return (self.use(key, written=written),)


def _digits(text: str) -> bool:
    """ASCII digits only (``str.isdigit`` also takes "²", which `int` refuses)."""
    return text.isascii() and text.isdigit()


def _check_scale(v: float) -> float:
    if not math.isfinite(v) or v == 0.0:
        raise ValueError("scale must be a finite non-zero number")
    return v


class OpcUaAddress(_Address):
    """An OPC UA node, e.g. ``ns=2;s=Machine.Bearing`` or ``ns=3;i=1001``."""

    node: str
    scale: float = 1.0

    @field_validator("node")
    @classmethod
    def _node(cls, v: str) -> str:
        v = v.strip()
        parts = dict(p.split("=", 1) for p in v.split(";") if "=" in p)
        kinds = {"i", "s", "g", "b"}
        if not v or not (kinds & parts.keys()) or any(
                "=" not in p for p in v.split(";")):
            raise ValueError(f"not an OPC UA NodeId string: {v!r} "
                             "(expected e.g. 'ns=2;s=Name' or 'ns=2;i=1001')")
        if "ns" in parts and not _digits(parts["ns"]):
            raise ValueError(f"namespace index must be an integer in {v!r}")
        if "i" in parts and not _digits(parts["i"]):
            raise ValueError(f"numeric identifier must be an integer in {v!r}")
        return v

    _scale = field_validator("scale")(_check_scale)

    def describe(self) -> str:
        return self.node

    def footprint(self) -> Footprint:
        return Footprint(("opcua", _canonical_node(self.node)), 0, 1, "node")


def _canonical_node(node: str) -> str:
    """One spelling per node: namespace 0 when none is given, numeric
    identifiers without leading zeros (``i=0042`` and ``ns=0;i=42`` are one node)."""
    parts = dict(p.split("=", 1) for p in node.split(";"))
    ns = f"nsu={parts.pop('nsu')}" if "nsu" in parts else f"ns={int(parts.pop('ns', '0'))}"
    if "i" in parts:
        parts["i"] = str(int(parts["i"]))
    return ";".join([ns, *(f"{k}={v}" for k, v in sorted(parts.items()))])


S7Type = Literal["REAL", "INT", "DINT", "WORD"]
S7_SIZES: dict[str, int] = {name: enc.size for name, enc in S7_TYPES.items()}


class S7Address(_Address):
    """A value in an S7 data block (big-endian). Integers carry a scale:
    engineering value = raw * scale."""

    area: Literal["DB"] = "DB"
    db: Annotated[int, Field(ge=1, le=65535)]
    offset: Annotated[int, Field(ge=0, le=65535)]
    type: S7Type = "REAL"
    scale: float = 1.0

    _scale = field_validator("scale")(_check_scale)

    @property
    def size(self) -> int:
        return S7_SIZES[self.type]

    @property
    def encoding(self) -> Encoding:
        return S7_TYPES[self.type]

    def footprint(self) -> Footprint:
        return Footprint(("s7", self.area, self.db), self.offset, self.offset + self.size,
                         "byte")

    def describe(self) -> str:
        return f"DB{self.db}.{self.offset}:{self.type}"


ModbusType = Literal["float32", "int32", "int16", "uint16"]
MODBUS_WORDS: dict[str, int] = {name: enc.size // 2 for name, enc in MODBUS_TYPES.items()}


class ModbusAddress(_Address):
    """A Modbus register value. Two-register types use `word_order`
    ("big": high word first). Engineering value = raw * scale."""

    unit: Annotated[int, Field(ge=0, le=247)] = 1
    kind: Literal["holding", "input"] = "holding"
    address: Annotated[int, Field(ge=0, le=65535)]
    type: ModbusType = "float32"
    word_order: Literal["big", "little"] = "big"
    scale: float = 1.0

    _scale = field_validator("scale")(_check_scale)

    @property
    def count(self) -> int:
        return MODBUS_WORDS[self.type]

    @property
    def encoding(self) -> Encoding:
        return MODBUS_TYPES[self.type]

    def footprint(self) -> Footprint:
        return Footprint(("modbus", self.unit, self.kind), self.address,
                         self.address + self.count, "register")

    @model_validator(mode="after")
    def _fits(self) -> ModbusAddress:
        if self.address + self.count - 1 > 65535:
            raise ValueError(f"{self.type} at {self.address} runs past register 65535")
        return self

    def describe(self) -> str:
        return f"unit{self.unit}/{self.kind}/{self.address}:{self.type}"


#: FOCAS PMC address types (pmc_rdpmcrng adr_type).
PMC_AREAS: dict[str, int] = {"G": 0, "F": 1, "Y": 2, "X": 3, "A": 4, "R": 5, "T": 6,
                             "K": 7, "C": 8, "D": 9, "M": 10, "N": 11, "E": 12, "Z": 13}
#: FOCAS PMC data types: code and byte size.
PMC_TYPES: dict[str, tuple[int, int]] = {
    name: (code, PMC_ENCODINGS[name].size)
    for name, code in {"byte": 0, "word": 1, "long": 2, "float": 4, "double": 5}.items()}


PmcArea = Literal["G", "F", "Y", "X", "A", "R", "T", "K", "C", "D", "M", "N", "E", "Z"]
PmcType = Literal["byte", "word", "long", "float", "double"]


class FocasPmcAddress(_Address):
    """A PMC area value read/written with pmc_rdpmcrng / pmc_wrpmcrng.
    `address` is the byte address; engineering value = raw * scale."""

    kind: Literal["pmc"] = "pmc"
    area: PmcArea
    address: Annotated[int, Field(ge=0, le=65535)]
    type: PmcType = "long"
    scale: float = 1.0

    _scale = field_validator("scale")(_check_scale)

    @property
    def size(self) -> int:
        return PMC_ENCODINGS[self.type].size

    @property
    def encoding(self) -> Encoding:
        return PMC_ENCODINGS[self.type]

    def footprint(self) -> Footprint:
        return Footprint(("pmc", self.area), self.address, self.address + self.size, "byte")

    def describe(self) -> str:
        return f"PMC {self.area}{self.address}:{self.type}"


class FocasDiagAddress(_Address):
    """A CNC diagnosis number read with cnc_diagnoss (e.g. 308 servo motor
    temperature per axis, 403 spindle motor temperature)."""

    kind: Literal["diag"]
    number: Annotated[int, Field(ge=0, le=65535)]
    axis: Annotated[int, Field(ge=-1, le=32)] = 0
    scale: float = 1.0

    _scale = field_validator("scale")(_check_scale)

    def describe(self) -> str:
        return f"DIAG {self.number} axis {self.axis}"


class FocasSpindleLoadAddress(_Address):
    """Spindle load % read with cnc_rdspload (`spindle` is 1-based; -1 = all)."""

    kind: Literal["spload"]
    spindle: Annotated[int, Field(ge=1, le=8)] = 1
    scale: float = 1.0

    _scale = field_validator("scale")(_check_scale)

    def describe(self) -> str:
        return f"SPLOAD {self.spindle}"


FocasAddress = Annotated[
    FocasPmcAddress | FocasDiagAddress | FocasSpindleLoadAddress,
    Field(discriminator="kind"),
]

# -- LinuxCNC HAL (`drivers.linuxcnc`; the kinds are explained in `drivers.linuxcnc_options`)

#: a HAL name: letters, digits and ``.-_:`` (HAL_NAME_LEN is 47)
_HAL_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.:\-]{0,46}")
HalName = Annotated[str, Field(min_length=1, max_length=47)]


def hal_name(v: str) -> str:
    if not _HAL_NAME.fullmatch(v):
        raise ValueError(f"not a HAL name: {v!r} (letters, digits, '.', '-', '_', ':'; "
                         "at most 47 characters)")
    return v


def _hal_signal(name: str) -> Footprint:
    """A HAL signal (or any HAL name a ``get`` reads): one cell, as an OPC UA node."""
    return Footprint(("hal", name), 0, 1, "signal")


def _hal_pin(pin: str) -> Footprint:
    """One of compd's own pins (``<component>.<pin>``): one cell, created once."""
    return Footprint(("hal-pin", pin), 0, 1, "pin")


def _pin_use(key: str, pin: str, written: bool) -> Use:
    # never merged as "the same read": compd creates each of its pins once
    return Use(key, _hal_pin(pin), written, ("pin", key))


class LinuxCncPin(_Address):
    """compd's own HAL pin joined to the signal ``net`` (`drivers.linuxcnc_options`)."""

    kind: Literal["pin"] = "pin"
    pin: HalName
    net: HalName
    type: Literal["float", "s32", "u32", "bit"] = "float"
    scale: float = 1.0
    invert: bool = False

    _names = field_validator("pin", "net")(hal_name)
    _scale = field_validator("scale")(_check_scale)

    @model_validator(mode="after")
    def _invert_bits(self) -> LinuxCncPin:
        if self.invert and self.type != "bit":
            raise ValueError("invert is for a bit pin only")
        return self

    @property
    def encoding(self) -> Encoding:
        return HAL_TYPES[self.type]

    def footprint(self) -> Footprint:
        """The signal it joins (the value the machine shares)."""
        return _hal_signal(self.net)

    def uses(self, key: str, *, written: bool) -> tuple[Use, ...]:
        """The signal (reads of one signal in one type are one value; HAL lets one
        pin write a signal) and compd's pin of that name (created once)."""
        return (Use(key, self.footprint(), written, ("signal", self.net, self.type)),
                _pin_use(key, self.pin, written))

    def describe(self) -> str:
        return f"{self.pin}<->{self.net}:{self.type}"


class LinuxCncEoffset(_Address):
    """An axis' external offset in counts (`drivers.linuxcnc_options`)."""

    kind: Literal["eoffset"]
    axis: Literal["x", "y", "z", "a", "b", "c", "u", "v", "w"] = "z"
    counts_net: HalName = "compd-eoffset-counts"
    enable_net: HalName = "compd-eoffset-enable"
    #: controller units per count (the output's unit: um with 1 µm counts -> 1.0)
    scale: float = 1.0
    #: axis.L.eoffset-scale as the HAL file sets it (machine units per count); checked
    eoffset_scale: float | None = None
    #: the type compd's count arithmetic sees (whole counts)
    type: Literal["s32"] = "s32"

    _names = field_validator("counts_net", "enable_net")(hal_name)

    @field_validator("scale", "eoffset_scale")
    @classmethod
    def _positive(cls, v: float | None) -> float | None:
        if v is not None and (not math.isfinite(v) or v <= 0.0):
            raise ValueError("must be a finite positive number")
        return v

    @property
    def encoding(self) -> Encoding:
        return HAL_TYPES[self.type]

    @property
    def pins(self) -> tuple[str, str]:
        """compd's two pins for this axis's offset (counts, enable): Z's keep their
        first names, ``eoffset-counts`` and ``eoffset-enable``; another axis's carry
        its letter (``eoffset-x-counts``), so that one component holds an offset per
        axis."""
        if self.axis == "z":
            return "eoffset-counts", "eoffset-enable"
        return f"eoffset-{self.axis}-counts", f"eoffset-{self.axis}-enable"

    def footprint(self) -> Footprint:
        """The counts signal (the value written)."""
        return _hal_signal(self.counts_net)

    def uses(self, key: str, *, written: bool) -> tuple[Use, ...]:
        """Both signals it drives and compd's two pins that drive them
        (`pins`)."""
        return (Use(key, self.footprint(), written, ("signal", self.counts_net, "s32")),
                Use(key, _hal_signal(self.enable_net), written,
                    ("signal", self.enable_net, "bit")),
                _pin_use(key, self.pins[0], written),
                _pin_use(key, self.pins[1], written))

    def describe(self) -> str:
        return f"axis.{self.axis}.eoffset-counts<-{self.counts_net}"


class LinuxCncGet(_Address):
    """Read only: any HAL pin, signal or parameter by its name, as ``halcmd
    getp`` reads it (``motion.motion-enabled``, ``axis.z.eoffset``), × ``scale``
    (a bit: 0 or 1, inverted with ``invert``). No ``net`` line needed."""

    kind: Literal["get"]
    hal: HalName
    scale: float = 1.0
    invert: bool = False

    _names = field_validator("hal")(hal_name)
    _scale = field_validator("scale")(_check_scale)

    def footprint(self) -> Footprint:
        """The HAL name it reads (a signal compd writes reads compd's own value)."""
        return _hal_signal(self.hal)

    def describe(self) -> str:
        return f"getp {self.hal}"


LinuxCncAddress = LinuxCncPin | LinuxCncEoffset | LinuxCncGet

Address = OpcUaAddress | S7Address | ModbusAddress | FocasPmcAddress | FocasDiagAddress \
    | FocasSpindleLoadAddress | LinuxCncPin | LinuxCncEoffset | LinuxCncGet

def __getattr__(name: str) -> Any:
    """``ADDRESS_TYPES``: protocol name -> the address model(s) it accepts,
    read from the protocol registry (`drivers.protocols`) when first asked."""
    if name == "ADDRESS_TYPES":
        from drivers.protocols import PROTOCOLS

        return {spec.name: spec.address_types() for spec in PROTOCOLS.values()}
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
