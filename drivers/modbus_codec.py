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

#: Modbus limit for one read request (function codes 3 and 4).
MAX_READ_REGISTERS = 125
#: Modbus limit for one write-multiple request (function code 16).
MAX_WRITE_REGISTERS = 123
#: Largest gap of unrequested registers a block read may span to merge two reads.
DEFAULT_MAX_GAP = 8

_INT_RANGES: dict[str, tuple[int, int]] = {
    "int16": (-0x8000, 0x7FFF),
    "uint16": (0, 0xFFFF),
    "int32": (-0x8000_0000, 0x7FFF_FFFF),
}


class ValueOutOfRangeError(BadAddress, ValueError):
    """A value cannot be encoded in its address's type and scale."""


def decode(address: ModbusAddress, registers: Sequence[int]) -> float:
    """Engineering value of the `address.count` registers given."""
    words = list(registers[: address.count])
    if address.type == "uint16":
        return words[0] * address.scale
    if address.type == "int16":
        raw = words[0] - 0x10000 if words[0] & 0x8000 else words[0]
        return raw * address.scale
    if address.word_order == "little":
        words.reverse()
    data = struct.pack(">HH", words[0], words[1])
    if address.type == "float32":
        value: float = struct.unpack(">f", data)[0]
        return value * address.scale
    raw_int: int = struct.unpack(">i", data)[0]
    return raw_int * address.scale


def encode(address: ModbusAddress, value: float, *, channel: str | None = None) -> list[int]:
    """Registers holding `value` at `address`; `ValueOutOfRangeError` when it does not fit."""
    where = {"channel": channel, "address": address.describe()}
    if address.type == "float32":
        raw_f = value / address.scale
        if math.isfinite(raw_f) and abs(raw_f) > 3.4028234663852886e38:
            raise ValueOutOfRangeError(f"{value!r} does not fit a float32", **where)
        words = list(struct.unpack(">HH", struct.pack(">f", raw_f)))
    else:
        if not math.isfinite(value):
            raise ValueOutOfRangeError(f"{value!r} cannot be stored in an integer register",
                                  **where)
        raw = round(value / address.scale)
        low, high = _INT_RANGES[address.type]
        if not low <= raw <= high:
            raise ValueOutOfRangeError(
                f"{value!r} at scale {address.scale} needs raw {raw}, outside "
                f"{address.type} range {low}..{high}", **where)
        if address.type != "int32":
            return [raw & 0xFFFF]
        words = list(struct.unpack(">HH", struct.pack(">i", raw)))
    if address.word_order == "little":
        words.reverse()
    return words


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
    groups: dict[tuple[int, str], list[tuple[str, ModbusAddress]]] = {}
    for name, addr in items:
        groups.setdefault((addr.unit, addr.kind), []).append((name, addr))
    spans: list[Span] = []
    for (unit, kind), members in sorted(groups.items()):
        members.sort(key=lambda m: (m[1].address, m[1].count))
        current: list[tuple[str, ModbusAddress]] = []
        start = end = 0  # end is exclusive
        for name, addr in members:
            a_end = addr.address + addr.count
            if current and addr.address - end <= max_gap and \
                    max(end, a_end) - start <= max_count:
                current.append((name, addr))
                end = max(end, a_end)
                continue
            if current:
                spans.append(Span(unit, kind, start, end - start, tuple(current)))
            current, start, end = [(name, addr)], addr.address, a_end
        if current:
            spans.append(Span(unit, kind, start, end - start, tuple(current)))
    return spans


def plan_writes(items: Iterable[tuple[str, ModbusAddress, list[int]]]
                ) -> list[tuple[Span, list[int]]]:
    """Merge writes of back-to-back registers of one unit into one
    write-multiple request (no gaps: a write must not touch registers it was
    not given), so a record like {offset, heartbeat, status} lands at once."""
    ordered = sorted(items, key=lambda it: (it[1].unit, it[1].address))
    out: list[tuple[Span, list[int]]] = []
    current: list[tuple[str, ModbusAddress]] = []
    words: list[int] = []
    unit = start = 0
    for name, addr, regs in ordered:
        if current and addr.unit == unit and addr.address == start + len(words) and \
                len(words) + len(regs) <= MAX_WRITE_REGISTERS:
            current.append((name, addr))
            words.extend(regs)
            continue
        if current:
            out.append((Span(unit, "holding", start, len(words), tuple(current)), words))
        current, words, unit, start = [(name, addr)], list(regs), addr.unit, addr.address
    if current:
        out.append((Span(unit, "holding", start, len(words), tuple(current)), words))
    return out
