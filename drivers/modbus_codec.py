"""Register encoding for Modbus values and the block-read planner.

Pure functions, no I/O: the driver (`drivers.modbus`) and the simulated
controller (`drivers.sim.modbus_server`) share them, so both ends agree on
what a `ModbusAddress` means on the wire.

Encoding: registers are 16-bit words sent big-endian (Modbus fixes the byte
order); two-register types (float32, int32) put the high word first when
`word_order` is "big" and the low word first when "little". Integer types
carry a scale: engineering value = raw * scale, so on write
raw = round(value / scale), refused when it does not fit the type.
Worked number: int16 at scale 0.1 holding 215 reads as 21.5 °C; writing
-3276.9 would need raw -32769 and is refused.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from drivers.addresses import ModbusAddress
from drivers.errors import BadAddress
from drivers.plans import Run, cover

#: Modbus limit for one read request (function codes 3 and 4).
MAX_READ_REGISTERS = 125
#: Modbus limit for one write-multiple request (function code 16).
MAX_WRITE_REGISTERS = 123
#: Largest gap of unrequested registers a block read may span to merge two reads.
DEFAULT_MAX_GAP = 8


class ValueOutOfRangeError(BadAddress, ValueError):
    """A value cannot be encoded in its address's type and scale."""


_HH = struct.Struct(">HH")
_F32 = struct.Struct(">f")


def decode(address: ModbusAddress, registers: Sequence[int]) -> float:
    """Engineering value of the `address.count` registers given."""
    return decode_at(address, registers, 0)


def decode_at(address: ModbusAddress, registers: Sequence[int], offset: int) -> float:
    """Engineering value of the `address.count` registers from `registers[offset]`
    (a read's whole span, decoded in place: no copy per value)."""
    kind = address.type
    hi = registers[offset]
    if kind == "uint16":
        return hi * address.scale
    if kind == "int16":
        return (hi - 0x10000 if hi & 0x8000 else hi) * address.scale
    lo = registers[offset + 1]
    if address.word_order == "little":
        hi, lo = lo, hi
    if kind == "float32":
        value: float = _F32.unpack(_HH.pack(hi, lo))[0]
        return value * address.scale
    raw = (hi << 16) | lo
    return (raw - 0x100000000 if raw & 0x80000000 else raw) * address.scale


def encode(address: ModbusAddress, value: float, *, channel: str | None = None) -> list[int]:
    """Registers holding `value` at `address`; `ValueOutOfRangeError` when it does not fit."""
    enc = address.encoding
    if not enc.integer:
        raw_f = value / address.scale
        if math.isfinite(raw_f) and not enc.lo <= raw_f <= enc.hi:
            raise _refused(f"{value!r} does not fit a float32", address, channel)
        words = list(_WORDS.unpack(enc.big.pack(raw_f)))
    else:
        if not math.isfinite(value):
            raise _refused(f"{value!r} cannot be stored in an integer register", address,
                           channel)
        raw = round(value / address.scale)
        if not enc.lo <= raw <= enc.hi:
            raise _refused(f"{value!r} at scale {address.scale} needs raw {raw}, outside "
                           f"{address.type} range {enc.lo}..{enc.hi}", address, channel)
        if enc.size == 2:
            return [raw & 0xFFFF]
        words = list(_WORDS.unpack(enc.big.pack(raw)))
    if address.word_order == "little":
        words.reverse()
    return words


#: two registers as sent: big-endian 16-bit words
_WORDS = struct.Struct(">HH")


def _refused(why: str, address: ModbusAddress, channel: str | None) -> ValueOutOfRangeError:
    return ValueOutOfRangeError(why, channel=channel, address=address.describe())


@dataclass(frozen=True, slots=True)
class Span:
    """One read or write request: registers [start, start + count) of one
    (unit, kind), covering the named items."""

    unit: int
    kind: str
    start: int
    count: int
    items: tuple[tuple[str, ModbusAddress], ...]

    def describe(self) -> str:
        return f"unit{self.unit}/{self.kind}/{self.start}+{self.count}"

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(name for name, _ in self.items)

    def where(self) -> tuple[tuple[str, ...], str]:
        """(channel, address) as errors name them."""
        return self.names, self.describe()


def plan_reads(items: Iterable[tuple[str, ModbusAddress]], *,
               max_gap: int = DEFAULT_MAX_GAP,
               max_count: int = MAX_READ_REGISTERS) -> list[Span]:
    """Group items by (unit, kind) and cover them with as few contiguous
    reads as possible: neighbours merge while the gap of unrequested
    registers is at most `max_gap` and the span stays within `max_count`."""
    return [_span(run) for run in cover(items, max_gap=max_gap, max_cells=max_count)]


def plan_writes(items: Iterable[tuple[str, ModbusAddress, list[int]]]
                ) -> list[tuple[Span, list[int]]]:
    """Merge writes of back-to-back registers of one unit into one
    write-multiple request (no gaps: a write must not touch registers it was
    not given), so a record like {offset, heartbeat, status} lands at once."""
    given = list(items)
    words = {name: regs for name, _, regs in given}
    spans = write_spans([(name, addr) for name, addr, _ in given])
    return [(span, [w for name, _ in span.items for w in words[name]]) for span in spans]


def write_spans(items: Iterable[tuple[str, ModbusAddress]]) -> list[Span]:
    """The requests of `plan_writes`, without the words (a driver keeps them
    per set of names)."""
    return [_span(run) for run in cover(items, max_gap=0, max_cells=MAX_WRITE_REGISTERS,
                                        join_overlaps=False)]


def _span(run: Run[ModbusAddress]) -> Span:
    _, unit, kind = run.space
    return Span(int(unit), str(kind), run.start, run.stop - run.start, run.items)
