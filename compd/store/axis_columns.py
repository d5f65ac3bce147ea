"""The recorder's per-axis rows (table ``axes``, `compd.store.schema.AXIS_COLUMNS`) as
numpy columns, and the names they take beside a sample in ``compd export``.

`axis_fields` is what a SELECT reads of an axis row (NULL for a column a file of an
older compd lacks); `axis_columns` builds its columns: ``axis``, ``state``, ``cause``
(str), ``in_force`` (bool), the rest float64 (NaN where none was recorded).

In an export each axis the recorder holds (`known_axes`: x, y, z, tool) has one
column per `EXPORT_AXIS_COLUMNS`, named ``<axis>.<column>`` (``x.value_um``,
``x.state``…); `is_axis_column` tells such a name.
"""

from __future__ import annotations

import functools
from collections.abc import Iterable
from typing import Any

import numpy as np

from compd.store.columns import Columns, floats
from compd.store.schema import AXIS_ADDED_COLUMNS, AXIS_COLUMNS

#: an axis row's text columns and its one flag; every other column is a number
AXIS_TEXT_COLUMNS = ("axis", "state", "cause")
AXIS_FLAG_COLUMNS = ("in_force",)
#: an axis's columns in an export, each as ``<axis>.<column>``: all but the axis name
EXPORT_AXIS_COLUMNS = AXIS_COLUMNS[1:]


@functools.cache
def known_axes() -> tuple[str, ...]:
    """The axes a recorder may hold, in export order: ``[output.axes]``'s (x, y, z) and
    the tool direction. (Imported when first asked: the config's axis module is a
    fifth of a second that a recorder without axes never needs.)"""
    from compd.config.axis_outputs import TOOL
    from drivers.temp_comp import AXES

    return (*AXES, TOOL)


def axis_fields(have: Iterable[str]) -> tuple[str, ...]:
    """``axes.<column>`` of every `AXIS_COLUMNS`, NULL for a column added since an
    older compd wrote the file and not in `have` (its table's columns)."""
    present = set(have)
    return tuple(f"axes.{c}" if c in present or c not in AXIS_ADDED_COLUMNS else "NULL"
                 for c in AXIS_COLUMNS)


def axis_columns(rows: list[Any], first: int) -> Columns:
    """`AXIS_COLUMNS` of `rows`, whose field `first` is the first of them (the fields
    of `axis_fields`). Raises one of `compd.store.columns.CORRUPT` on a value the
    recorder cannot have written (a text where a number belongs)."""
    out: Columns = {}
    for i, name in enumerate(AXIS_COLUMNS, start=first):
        if name in AXIS_TEXT_COLUMNS:
            out[name] = np.array([str(r[i]) for r in rows], dtype=str)
        elif name in AXIS_FLAG_COLUMNS:
            out[name] = np.array([bool(r[i]) for r in rows], dtype=bool)
        else:
            out[name] = floats(r[i] for r in rows)
    return out


def is_axis_column(name: str) -> bool:
    """Whether `name` is an export's ``<axis>.<column>``."""
    axis, dot, column = name.partition(".")
    return bool(dot) and column in EXPORT_AXIS_COLUMNS and axis in known_axes()
