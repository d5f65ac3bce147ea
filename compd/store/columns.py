"""A recorder batch's rows as numpy columns, and the SELECT list that keeps an
over-long field from reaching Python (`compd.store.reader` reads through both).

Columns of a batch (all of equal length): ``seq`` and ``cycle`` (int64; cycle
-1 when the daemon gave none), ``time_s`` (float64: the daemon's sample clock,
the same as ``mono_s``), ``mono_s``, ``wall_s``, ``offset_um`` (written),
``model_um``, ``valid`` (bool), ``state`` (str), then one float64 column per
channel named as the channel (NaN where missing or not finite),
``valid.<channel>`` (bool: a finite value and no reason recorded against it)
and ``contribution.<term>`` (float64) per model term. With ``detail=False``
(what a calibration record needs) only ``cycle``, ``mono_s``, ``offset_um``,
``model_um`` and the channels.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from compd.infiles import MAX_FIELD_CHARS

Columns = dict[str, npt.NDArray[Any]]

#: what a corrupt row raises while its columns are built
CORRUPT = (ValueError, TypeError, AttributeError, KeyError, OverflowError, RecursionError)
#: the text columns of the recorder's layout (`compd.store.schema`): their length is
#: measured as it is; any other column holds numbers
TEXT_COLUMNS = frozenset({"samples.state", "samples.channels", "samples.validity",
                           "samples.contributions", "probes.reason"})


def bounded_fields(columns: Sequence[str]) -> str:
    """`columns` ("table.column") for a SELECT, each NULL when longer than
    MAX_FIELD_CHARS, then one more: the name of the first such column (NULL when none),
    so that a 100 MB cell never reaches Python (SQLite reads it once to measure it).
    A number column is measured only when it holds a text or a blob: SQLite orders
    every number before any text or blob, so ``c >= ''`` is false for a number, which
    is never formatted to be measured (that, or typeof(), cost a third of a batch's
    read)."""
    def long(c: str) -> str:
        measured = f"length({c}) > {MAX_FIELD_CHARS}"
        return measured if c in TEXT_COLUMNS else f"({c} >= '' AND {measured})"

    bounded = [f"CASE WHEN {long(c)} THEN NULL ELSE {c} END" for c in columns]
    first = " ".join(f"WHEN {long(c)} THEN '{c.partition('.')[2]}'" for c in columns)
    return ", ".join([*bounded, f"CASE {first} END"])


def floats(values: Iterable[Any]) -> npt.NDArray[np.float64]:
    return np.array([math.nan if v is None else v for v in values], dtype=np.float64)


def json_object(text: Any) -> dict[str, Any]:
    value = json.loads(text)
    if not isinstance(value, dict):
        raise TypeError(f"{type(value).__name__}, not a JSON object")
    return value


def build_columns(rows: list[Any], channels: tuple[str, ...], terms: tuple[str, ...],
           detail: bool) -> Columns:
    """One batch's columns from its rows (rowid, seq, cycle, mono_s, wall_s,
    offset_um, model_um, valid, state, channels[, validity, contributions])."""
    mono = floats(r[3] for r in rows)
    out: Columns = {}
    if detail:
        out["seq"] = np.array([r[1] for r in rows], dtype=np.int64)
    out["cycle"] = np.array([-1 if r[2] is None else r[2] for r in rows], dtype=np.int64)
    if detail:
        out["time_s"] = mono.copy()
    out["mono_s"] = mono
    if detail:
        out["wall_s"] = floats(r[4] for r in rows)
    out["offset_um"] = floats(r[5] for r in rows)
    out["model_um"] = floats(r[6] for r in rows)
    if detail:
        out["valid"] = np.array([bool(r[7]) for r in rows], dtype=bool)
        out["state"] = np.array([str(r[8]) for r in rows], dtype=str)
    values = [json_object(r[9]) for r in rows]
    for name in channels:
        out[name] = floats(v.get(name) for v in values)
    if not detail:
        return out
    validity = [json_object(r[10]) for r in rows]
    for name in channels:
        out[f"valid.{name}"] = np.array(
            [v.get(name) is not None and w.get(name) is None
             for v, w in zip(values, validity, strict=True)], dtype=bool)
    contributions = [json_object(r[11]) for r in rows]
    for term in terms:
        out[f"contribution.{term}"] = floats(c.get(term) for c in contributions)
    return out

