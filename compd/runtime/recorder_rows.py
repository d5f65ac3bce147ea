"""The recorder's rows as SQLite stores them (`compd.runtime.recorder`): one
commit's `Batch`, formatted on the caller's thread (no I/O) before the writer
commits it. Non-finite floats become NULL (JSON null); each channel value, its
validity and each term's contribution go into the JSON columns of
`compd.store.schema`'s layout, each axis's part of the cycle into table ``axes``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from compd.core.record import RecordRow
from compd.store.schema import PROBE_COLUMNS

__all__ = ["Batch"]


def _num(value: float | None) -> float | None:
    """A float for SQLite/JSON; non-finite and missing become NULL/null."""
    if value is None:
        return None
    v = float(value)
    return v if math.isfinite(v) else None


#: each name and text as a JSON string, encoded once (a row's keys and reasons are
#: the same few every cycle); cleared when it grows past `_QUOTED_MAX`
_QUOTED: dict[str, str] = {}
_QUOTED_MAX = 4096


def _quoted(text: str) -> str:
    q = _QUOTED.get(text)
    if q is None:
        if len(_QUOTED) >= _QUOTED_MAX:
            _QUOTED.clear()
        q = _QUOTED[text] = json.dumps(text)
    return q


def _json_numbers(values: Mapping[str, float | None]) -> str:
    """`values` as compact JSON, non-finite as null: the text `json.dumps(..., separators=
    (",", ":"))` makes (a float's repr), without its encoder's set-up per call."""
    isfinite = math.isfinite
    parts = []
    for k, v in values.items():
        f = None if v is None else float(v)
        parts.append(f"{_quoted(str(k))}:{'null' if f is None or not isfinite(f) else repr(f)}")
    return "{" + ",".join(parts) + "}"


def _json_reasons(validity: Mapping[str, str | None]) -> str:
    """The invalid channels' reasons as compact JSON (valid channels left out)."""
    return "{" + ",".join(f"{_quoted(str(k))}:{_quoted(str(v))}"
                          for k, v in validity.items() if v is not None) + "}"


def _tuple(seq: int, row: RecordRow) -> tuple[Any, ...]:
    return (seq, row.seq, float(row.mono_s), float(row.wall_s), _num(row.offset_um),
            _num(row.model_um), str(row.state), 1 if row.valid else 0,
            _json_numbers(row.channels), _json_reasons(row.validity),
            _json_numbers(row.contributions), _num(row.attempted_um),
            1 if row.complete else 0)


def _nums(values: Iterable[float | None]) -> list[float | None]:
    """`_num` of each of `values` (one call for an axis's eleven numbers)."""
    isfinite = math.isfinite
    return [None if x is None or not isfinite(v := float(x)) else v for x in values]


def _axis_tuples(seq: int, row: RecordRow) -> list[tuple[Any, ...]]:
    """The ``axes`` rows of one sample (`compd.store.schema.AXIS_COLUMNS`), one per
    axis (a `compd.core.axes.AxisRow` each)."""
    out = []
    for axis, a in row.axes.items():
        v, s = a.value, a.slope
        out.append((seq, str(axis), str(a.state), str(a.cause), 1 if a.in_force else 0,
                    *_nums((v.stage, v.sent, v.confirmed, v.model,
                            s.stage, s.sent, s.confirmed, s.model,
                            a.reference_mm, a.position_mm, a.offset_um))))
    return out


@dataclass(frozen=True, slots=True)
class Batch:
    """One commit's rows, formatted: the ``samples``, ``probe`` and ``axes`` rows
    and the names lists they extend (written to ``meta`` when they grew)."""

    first: int
    count: int
    samples: list[tuple[Any, ...]]
    probes: list[tuple[Any, ...]]
    axes: list[tuple[Any, ...]]
    channels: list[str]
    terms: list[str]

    @classmethod
    def of(cls, first: int, rows: Sequence[RecordRow], channels: list[str],
           terms: list[str]) -> Batch:
        """`rows` numbered from `first`, with the channel and term names known so
        far (`channels`, `terms`); ValueError, TypeError or AttributeError: a row
        that cannot be stored."""
        samples = [_tuple(first + i, r) for i, r in enumerate(rows)]
        axes = [t for i, r in enumerate(rows) if r.axes for t in _axis_tuples(first + i, r)]
        probes = [(first + i, *(r.probe.get(c) for c in PROBE_COLUMNS))
                  for i, r in enumerate(rows) if r.probe is not None]
        return cls(first, len(rows), samples, probes, axes,
                   channels + _new_names(channels, (r.channels for r in rows)),
                   terms + _new_names(terms, (r.contributions for r in rows)))


def _new_names(known: list[str], groups: Iterable[Mapping[str, Any]]) -> list[str]:
    """The names in `groups` not in `known`, in the order first seen."""
    seen = set(known)
    return list(dict.fromkeys(str(n) for g in groups for n in g if n not in seen))
