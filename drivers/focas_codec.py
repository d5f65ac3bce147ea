"""FANUC PMC value encodings and range planning (no I/O; the planner is
`drivers.plans.cover`).

PMC memory is little-endian (the low byte of word D100 is D100). Reads and
writes move raw bytes (data type 0) over byte ranges, and values are decoded
here; engineering value = raw * scale, integers rounded and range-checked.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

from drivers.addresses import FocasPmcAddress
from drivers.plans import Run, cover

#: longest byte range read in one pmc_rdpmcrng
MAX_RANGE_BYTES = 1024


def pmc_size(a: FocasPmcAddress) -> int:
    return a.size


def decode_pmc(a: FocasPmcAddress, data: bytes | bytearray, at: int = 0) -> float:
    (raw,) = a.encoding.little.unpack_from(data, at)
    return float(raw) * a.scale


def encode_pmc(a: FocasPmcAddress, value: float, *, saturate: bool = False) -> bytes:
    """Bytes of `value`; ValueError when not representable (`saturate`
    clamps integers instead, as an analog card would)."""
    if not math.isfinite(value):
        raise ValueError(f"{value!r} is not a finite number")
    raw = value / a.scale
    enc = a.encoding
    fmt = enc.little
    if enc.integer:
        lo, hi = int(enc.lo), int(enc.hi)
        raw_int = round(raw)
        if saturate:
            raw_int = min(max(raw_int, lo), hi)
        elif not lo <= raw_int <= hi:
            raise ValueError(f"{value!r} (raw {raw_int}) outside PMC {a.type} range {lo}..{hi}")
        return fmt.pack(raw_int)
    try:
        return fmt.pack(raw)
    except OverflowError as exc:
        raise ValueError(f"{value!r} overflows a PMC {a.type}") from exc


@dataclass(frozen=True, slots=True)
class PmcRange:
    """One pmc_rdpmcrng / pmc_wrpmcrng request: bytes start..end of one area."""

    area: str
    start: int
    end: int  # inclusive
    names: tuple[str, ...]

    @property
    def size(self) -> int:
        return self.end - self.start + 1


def read_ranges(items: Iterable[tuple[str, FocasPmcAddress]]) -> list[PmcRange]:
    """One range per area (split only past MAX_RANGE_BYTES)."""
    return [_range(run) for run in cover(items, max_cells=MAX_RANGE_BYTES)]


def write_runs(items: Iterable[tuple[str, FocasPmcAddress]]) -> list[PmcRange]:
    """Runs of byte-adjacent values of one area: one write request each."""
    return [_range(run) for run in cover(items, max_gap=0, join_overlaps=False)]


def _range(run: Run[FocasPmcAddress]) -> PmcRange:
    return PmcRange(str(run.space[1]), run.start, run.stop - 1, run.names)
