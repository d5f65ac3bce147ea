"""The controller memory an address occupies, and the first clash among several.

A `Footprint` is a half-open run of cells ``[start, stop)`` in one memory
`space`: Modbus registers of one unit and table, bytes of one S7 data block
or one PMC area, or a whole OPC UA node (one cell; two node ids clash only
when they name the same node), or a LinuxCNC HAL signal or one of compd's own
HAL pins (one cell each, by name; a pin address has both: `Address.uses`).
`Address.footprint()` (`drivers.addresses`) gives each address's; the codecs
write exactly those cells
(tests/drivers/test_footprint.py holds them to it).

`first_clash(uses)` is the rule the daemon's config and the HIL drive map
both apply: an address that is **written** may share no cell with any other
address; addresses that are only **read** may share cells only when they
read the same value (the same cells in the same encoding, e.g. one sensor
under two channel names): a read that covers part of another value, or the
same cells as another type, decodes bytes that belong to something else.

Cells are whole registers and bytes: no address type addresses a single bit
today. One that does (an S7 BOOL, a PMC bit) must count its footprint in
bits; counted in bytes, two bits of one byte would be taken for a clash.
"""

from __future__ import annotations

from collections.abc import Hashable, Sequence
from dataclasses import dataclass
from typing import NamedTuple

#: a memory space: ("modbus", unit, kind), ("s7", "DB", db), ("pmc", area), ("opcua", node),
#: ("hal", signal) and ("hal-pin", compd's pin)
Space = tuple[str | int, ...]


class Footprint(NamedTuple):
    """Cells ``[start, stop)`` of `space`, counted in `unit` ("register",
    "byte" or "node"). A named tuple: the planners make one per address."""

    space: Space
    start: int
    stop: int
    unit: str

    def overlap(self, other: Footprint) -> Footprint | None:
        """The cells both occupy (None when they share none)."""
        if self.space != other.space:
            return None
        start, stop = max(self.start, other.start), min(self.stop, other.stop)
        return Footprint(self.space, start, stop, self.unit) if start < stop else None

    def cells(self) -> range:
        return range(self.start, self.stop)

    def describe(self) -> str:
        """``holding register 1 of unit 1``, ``DB3 bytes 0..3``, ``PMC D100..103``,
        ``node ns=2;s=X``, ``HAL signal compd-offset``, ``HAL pin heartbeat``."""
        one = self.stop - self.start == 1
        span = f"{self.start}" if one else f"{self.start}..{self.stop - 1}"
        kind, cells = self.space[0], self.unit if one else f"{self.unit}s"
        if kind == "modbus":
            return f"{self.space[2]} {cells} {span} of unit {self.space[1]}"
        if kind == "s7":
            return f"{self.space[1]}{self.space[2]} {cells} {span}"
        if kind == "pmc":
            return f"PMC {self.space[1]}{span}"
        if kind == "opcua":
            return f"node {self.space[1]}"
        if kind in ("hal", "hal-pin"):
            return f"HAL {self.unit} {self.space[1]}"
        return f"{' '.join(str(s) for s in self.space)} {cells} {span}"


@dataclass(frozen=True, slots=True)
class Use:
    """One configured address: its `key` (for messages), its footprint (None:
    not controller memory, e.g. a FOCAS diagnosis), whether compd `written`
    writes it, and `value`: what its cells are read as (equal for two reads
    of the same value)."""

    key: str
    footprint: Footprint | None
    written: bool
    value: Hashable = None


@dataclass(frozen=True, slots=True)
class Clash:
    """`second` (later in the order given) overlaps `first` at `cells`."""

    first: Use
    second: Use
    cells: Footprint

    def reason(self) -> str:
        """The message for `second`'s key."""
        written = self.first.written + self.second.written
        if self.cells.unit == "pin":
            return (f"names compd's {self.cells.describe()} as {self.first.key} does "
                    "(HAL creates each pin of a component once)")
        why = ("both are written: each write overwrites part of the other" if written == 2
               else "one is written: a write there changes the other's value"
               if written == 1 else "two reads decode the same cells as different values")
        return f"overlaps {self.first.key} at {self.cells.describe()} ({why})"


def first_clash(uses: Sequence[Use]) -> Clash | None:
    """A clash among `uses` by the rule of the module docstring, or None.

    Identical reads are merged first (they may coincide), then each space is
    swept in address order, so thousands of addresses cost n·log n, not n²."""
    order = {id(u): i for i, u in enumerate(uses)}
    seen_reads: set[tuple[Footprint, Hashable]] = set()
    by_space: dict[Space, list[tuple[Footprint, Use]]] = {}
    for use in uses:
        fp = use.footprint
        if fp is None:
            continue
        if not use.written:
            if (fp, use.value) in seen_reads:
                continue
            seen_reads.add((fp, use.value))
        by_space.setdefault(fp.space, []).append((fp, use))
    found: list[Clash] = []
    for members in by_space.values():
        members.sort(key=lambda m: (m[0].start, m[0].stop, order[id(m[1])]))
        reach = members[0]  # the member reaching furthest so far
        for fp, use in members[1:]:
            cells = reach[0].overlap(fp)
            if cells is not None:
                first, second = sorted((reach[1], use), key=lambda u: order[id(u)])
                found.append(Clash(first, second, cells))
                break
            if fp.stop > reach[0].stop:
                reach = (fp, use)
    if not found:
        return None
    return min(found, key=lambda c: (order[id(c.second)], order[id(c.first)]))


__all__ = ["Clash", "Footprint", "Space", "Use", "first_clash"]
