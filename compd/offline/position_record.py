"""A calibration record with the displacement measured at several positions.

Its displacement columns are named ``dx_at_<x>mm_um`` (x the position along
the axis in mm to 0.001 mm, without trailing zeros: ``dx_at_0mm_um``, ``dx_at_200mm_um``,
``dx_at_-50mm_um``), one per position, every row a measuring pass (what
`compd sim --machine ballscrew --record` writes); the other columns are the
temperatures and the machine's state, read as by `compd fit`
(`compd.offline.records`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from compd.offline.records import FloatArray, Record, RecordError, read_record
from drivers.sim.ballscrew import parse_position_column


@dataclass(frozen=True)
class PositionRecord:
    """A record and its displacement columns, sorted by position."""

    record: Record
    positions_mm: tuple[float, ...]
    position_columns: tuple[str, ...]

    def displacements(self) -> FloatArray:
        """The measured displacements, rows × positions (µm)."""
        return np.column_stack([self.record.columns[c] for c in self.position_columns])


def position_record(record: Record) -> PositionRecord:
    """The displacement columns of a read record; RecordError naming the file when
    fewer than two positions are measured (a line needs two)."""
    found = sorted((x, name) for name in record.columns
                   if (x := parse_position_column(name)) is not None)
    if len({x for x, _ in found}) < 2:
        have = ", ".join(name for _, name in found) or "none"
        raise RecordError(f"{record.path}: displacement at {len(found)} position(s) ({have}); "
                          "value and slope need two or more columns dx_at_<x>mm_um")
    return PositionRecord(record, tuple(x for x, _ in found), tuple(n for _, n in found))


def read_position_record(path: str | Path) -> PositionRecord:
    """Read a record (`compd.offline.records.read_record`) and its position columns."""
    return position_record(read_record(path))


#: the columns `with_line_columns` derives: the value at the reference position (µm)
#: and the slope (µm/m) of the line through each row's displacements
VALUE_COLUMN = "value_um"
SLOPE_COLUMN = "slope_um_m"


def with_line_columns(record: Record, x0_mm: float) -> Record:
    """The record with two more columns, `VALUE_COLUMN` and `SLOPE_COLUMN`: per row
    the least-squares line through the displacements at its positions
    (`models.identify.positions.line_per_sample`), the value taken at `x0_mm`.
    RecordError when the record has fewer than two positions or already has a
    column of either name."""
    from models.identify.positions import line_per_sample

    pr = position_record(record)
    taken = sorted({VALUE_COLUMN, SLOPE_COLUMN} & set(record.columns))
    if taken:
        raise RecordError(f"{record.path}: already has column(s) {taken}, the names the "
                          "value and slope of --positions take")
    value, slope = line_per_sample(pr.positions_mm, pr.displacements(), x0_mm)
    return dataclasses.replace(record, columns={**record.columns, VALUE_COLUMN: value,
                                                SLOPE_COLUMN: slope})


def line_record(record: Record, x0_mm: float, output: str) -> Record:
    """What `compd fit --positions` fits: the record's temperatures and machine
    state, and of the line only `output` (`VALUE_COLUMN` or `SLOPE_COLUMN`). The
    displacements at the positions and the other half of the line are dropped: a
    measured displacement is never an input (a --term or --candidates naming one
    finds no such column)."""
    if output not in (VALUE_COLUMN, SLOPE_COLUMN):
        raise ValueError(f"output must be {VALUE_COLUMN} or {SLOPE_COLUMN}, got {output!r}")
    full = with_line_columns(record, x0_mm)
    columns = {name: v for name, v in record.columns.items()
               if parse_position_column(name) is None}
    columns[output] = full.columns[output]
    return dataclasses.replace(record, columns=columns)
