"""Big-endian S7 value encodings and request planning (no I/O; the planner
is `drivers.plans.cover`).

Engineering value = raw * scale. INT/DINT/WORD are rounded to the nearest
raw integer on write and refused when out of range (a wrapped offset on a
machine tool is worse than no offset).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from drivers.addresses import S7Address
from drivers.plans import Run, cover


def decode(address: S7Address, data: bytes | bytearray, at: int = 0) -> float:
    """The engineering value of `address` found at byte `at` of `data`."""
    (raw,) = address.encoding.big.unpack_from(data, at)
    return float(raw) * address.scale


def encode(address: S7Address, value: float) -> bytes:
    """The bytes of `value` for `address`; ValueError when not representable."""
    if not math.isfinite(value):
        raise ValueError(f"{value!r} is not a finite number")
    raw = value / address.scale
    enc = address.encoding
    if not enc.integer:
        if not enc.fits(raw):
            raise ValueError(f"{value!r} overflows a {address.type}")
        return enc.big.pack(raw)
    raw_int = round(raw)
    if not enc.fits(raw_int):
        raise ValueError(f"{value!r} (raw {raw_int}) outside {address.type} range "
                         f"{enc.lo}..{enc.hi}")
    return enc.big.pack(raw_int)


@dataclass(frozen=True, slots=True)
class Span:
    """One DB request covering several named addresses."""

    db: int
    start: int
    size: int
    names: tuple[str, ...]


def read_spans(addresses: Mapping[str, S7Address]) -> list[Span]:
    """One span per DB covering every requested value of that DB."""
    return [_span(run) for run in cover(addresses.items())]


def write_runs(items: Iterable[tuple[str, S7Address]]) -> list[Span]:
    """Group writes into runs of byte-adjacent values of one DB, so a run
    goes out as one db_write without touching bytes between values."""
    return [_span(run) for run in cover(items, max_gap=0, join_overlaps=False)]


def _span(run: Run[S7Address]) -> Span:
    return Span(int(run.space[2]), run.start, run.stop - run.start, run.names)
