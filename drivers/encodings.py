"""Raw value encodings, described once: size, struct code and raw range.

Every protocol stores a value in one of a few machine encodings (a 16-bit
signed integer, an IEEE float32, ...). This table is the one place their raw
ranges live; each protocol's type names map onto it (`S7_TYPES`,
`MODBUS_TYPES`, `PMC_ENCODINGS`, `HAL_TYPES` here, the OPC UA variant types in
`drivers.opcua_codec`), and the codecs, the address models
(`Address.raw_range`) and the daemon's config check all read it.

Worked number: ``ENCODINGS["int16"].range`` is (-32768, 32767); an int16 at
scale 0.1 therefore holds -3276.8 .. 3276.7 in engineering units.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

#: the largest finite IEEE 754 binary32 value
FLOAT32_MAX = 3.4028234663852886e38
#: the largest finite IEEE 754 binary64 value
FLOAT64_MAX = 1.7976931348623157e308


@dataclass(frozen=True, slots=True)
class Encoding:
    """One raw encoding: `size` bytes, `code` its `struct` letter (no byte
    order), and its inclusive raw range `lo`..`hi` (ints for an integer
    encoding, the largest finite values for a float)."""

    name: str
    size: int
    code: str
    lo: int | float
    hi: int | float
    #: raw values are integers (a write rounds to the nearest one)
    integer: bool = field(init=False, compare=False)
    #: the compiled big- and little-endian formats (codecs pack and unpack with them)
    big: struct.Struct = field(init=False, repr=False, compare=False)
    little: struct.Struct = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "integer", isinstance(self.lo, int))
        object.__setattr__(self, "big", struct.Struct(">" + self.code))
        object.__setattr__(self, "little", struct.Struct("<" + self.code))

    @property
    def range(self) -> tuple[int | float, int | float]:
        return self.lo, self.hi

    def fits(self, raw: float) -> bool:
        """Whether `raw` (already rounded for an integer encoding) is inside the range."""
        return self.lo <= raw <= self.hi


def _int(name: str, size: int, code: str, signed: bool) -> Encoding:
    bits = 8 * size
    if signed:
        return Encoding(name, size, code, -(1 << (bits - 1)), (1 << (bits - 1)) - 1)
    return Encoding(name, size, code, 0, (1 << bits) - 1)


ENCODINGS: dict[str, Encoding] = {e.name: e for e in (
    _int("int8", 1, "b", True), _int("uint8", 1, "B", False),
    _int("int16", 2, "h", True), _int("uint16", 2, "H", False),
    _int("int32", 4, "i", True), _int("uint32", 4, "I", False),
    _int("int64", 8, "q", True), _int("uint64", 8, "Q", False),
    Encoding("float32", 4, "f", -FLOAT32_MAX, FLOAT32_MAX),
    Encoding("float64", 8, "d", -FLOAT64_MAX, FLOAT64_MAX),
    #: one bit (a LinuxCNC HAL bit): 0 or 1
    Encoding("bit", 1, "?", 0, 1),
)}

#: S7 data types (big-endian in a DB)
S7_TYPES: dict[str, Encoding] = {"REAL": ENCODINGS["float32"], "INT": ENCODINGS["int16"],
                                 "DINT": ENCODINGS["int32"], "WORD": ENCODINGS["uint16"]}
#: Modbus value types (16-bit registers, big-endian words)
MODBUS_TYPES: dict[str, Encoding] = {name: ENCODINGS[name]
                                     for name in ("float32", "int32", "int16", "uint16")}
#: FANUC PMC data types (little-endian PMC memory)
PMC_ENCODINGS: dict[str, Encoding] = {"byte": ENCODINGS["int8"], "word": ENCODINGS["int16"],
                                      "long": ENCODINGS["int32"],
                                      "float": ENCODINGS["float32"],
                                      "double": ENCODINGS["float64"]}
#: LinuxCNC HAL pin types (hal_float_t is a C double; values pass as numbers, not bytes)
HAL_TYPES: dict[str, Encoding] = {"float": ENCODINGS["float64"], "s32": ENCODINGS["int32"],
                                  "u32": ENCODINGS["uint32"], "bit": ENCODINGS["bit"]}

__all__ = ["ENCODINGS", "FLOAT32_MAX", "FLOAT64_MAX", "HAL_TYPES", "MODBUS_TYPES",
           "PMC_ENCODINGS", "S7_TYPES", "Encoding"]
