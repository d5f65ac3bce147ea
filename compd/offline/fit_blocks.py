"""The inner held-out blocks `compd fit`'s last word is judged on
(`compd.offline.fit_judge`): stretches of the calibration rows of every kind
of "later" a machine meets, each held out in turn while the rest calibrates.

Cut from the spindle speed (the first speed column of the records): the
rows are split into stretches of one speed level (levels `LEVEL_SHARE` of the
top speed apart; a stretch shorter than `MIN_SHARE` of its record joins the
one before). Then, within each record:

- **cycle**: a stretch at a higher speed than the one before, with the lower
  stretch after it (a heat-up and its cool-down), neither the record's first
  nor its last stretch: a speed between those calibrated;
- **cool-down**: a stretch at a lower speed than the one before (from the
  bottom speed as from the top), not the last;
- **end**: the record's last stretch, calibrated on all before it.

A record without a speed column, or with fewer than three stretches or more
than `MAX_STRETCHES` (a shop day whose speed changes every few minutes), is
cut into equal parts of its usable rows instead: the interior ones and the
end. At most `MAX_PER_KIND` blocks of each kind, the latest kept. Only the
usable rows of a block are scored (`compd.offline.fit_terms.usable_rows`).

Worked number: the fl_thermal record (1250, 2500 and 3750 rpm for 4 h each,
each followed by 4 h at rest, then 5000 rpm): cycles at 2500 and 3750 rpm,
cool-downs from 1250, 2500 and 3750 rpm, the end at 5000 rpm: six blocks.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from models.identify.segments import Segments

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

#: two speeds are one level when closer than this share of the top speed
LEVEL_SHARE = 0.05
#: a stretch shorter than this share of its record joins the one before
MIN_SHARE = 0.02
#: a block is scored only with at least this many usable rows
MIN_BLOCK_ROWS = 10
#: more stretches than this: the record is cut into equal parts instead
MAX_STRETCHES = 16
#: at most this many blocks of each kind (the latest)
MAX_PER_KIND = 3
#: equal parts of a record cut without its speed
PARTS = 5


@dataclass(frozen=True)
class InnerBlock:
    #: what it is, e.g. "cool-down 20.1-24.1 h (from 3750 rpm)"
    name: str
    #: cycle, cool-down, end, interior
    kind: str
    #: its usable rows (of the records concatenated)
    rows: BoolArray


def _stretches(speed: FloatArray, lo: int, hi: int) -> list[tuple[int, int, float]]:
    """(start, end, level) of the runs of one speed level in rows lo … hi."""
    top = float(np.max(np.abs(speed[lo:hi]))) if hi > lo else 0.0
    if top <= 0.0 or not np.all(np.isfinite(speed[lo:hi])):
        return []
    q = np.round(speed[lo:hi] / (LEVEL_SHARE * top)).astype(np.int64)
    edges = [0, *(np.flatnonzero(np.diff(q)) + 1).tolist(), hi - lo]
    runs = [(lo + a, lo + b, float(np.median(speed[lo + a:lo + b])))
            for a, b in itertools.pairwise(edges)]
    least = max(1, round(MIN_SHARE * (hi - lo)))
    merged: list[tuple[int, int, float]] = []
    for s, e, lvl in runs:
        if merged and (e - s < least or abs(lvl - merged[-1][2]) < LEVEL_SHARE * top):
            ps, _, plvl = merged[-1]
            merged[-1] = (ps, e, plvl)
        else:
            merged.append((s, e, lvl))
    if len(merged) > 1 and merged[0][1] - merged[0][0] < least:  # a short start joins the next
        s0 = merged.pop(0)[0]
        _s1, e1, l1 = merged[0]
        merged[0] = (s0, e1, l1)
    return merged


def _hours(time_s: FloatArray | None, s: int, e: int) -> str:
    if time_s is None:
        return f"rows {s}-{e - 1}"
    return f"{time_s[s] / 3600.0:.1f}-{time_s[e - 1] / 3600.0:.1f} h"


def _usable_index(use: BoolArray, s: int, e: int) -> Any:
    """The indices of the usable rows of rows s … e-1: a range when every one is
    (no array of a month's indices, 21 MB), else the array of them."""
    if bool(use[s:e].all()):
        return range(s, e)
    return np.flatnonzero(use[s:e]) + s


def inner_blocks(seg: Segments, usable: BoolArray | None, speed: FloatArray | None = None,
                 time_s: FloatArray | None = None) -> list[InnerBlock]:
    """The inner held-out blocks (module docstring) of the records `seg`;
    `speed` and `time_s` over the records concatenated (None: none)."""
    use = np.ones(seg.total, dtype=bool) if usable is None else np.asarray(usable, dtype=bool)
    found: dict[str, list[InnerBlock]] = {"cycle": [], "cool-down": [], "interior": [],
                                          "end": []}

    def add(kind: str, name: str, s: int, e: int) -> None:
        rows = np.zeros(seg.total, dtype=bool)
        rows[s:e] = use[s:e]
        # a block must leave rows to calibrate on, and hold enough to be scored
        if int(rows.sum()) >= MIN_BLOCK_ROWS and int((use & ~rows).sum()) >= MIN_BLOCK_ROWS:
            found[kind].append(InnerBlock(name, kind, rows))

    for s, e in seg.bounds:
        idx = _usable_index(use, s, e)
        if len(idx) < 2 * MIN_BLOCK_ROWS:
            continue
        lo, hi = int(idx[0]), int(idx[-1]) + 1
        runs = _stretches(speed, lo, hi) if speed is not None else []
        if 3 <= len(runs) <= MAX_STRETCHES:
            for i, (a, b, lvl) in enumerate(runs):
                last = i == len(runs) - 1
                prev = runs[i - 1][2] if i else None
                if last:
                    add("end", f"end {_hours(time_s, a, b)} ({lvl:g} rpm)", a, b)
                    continue
                if prev is not None and lvl < prev:
                    add("cool-down", f"cool-down {_hours(time_s, a, b)} (from {prev:g} rpm)",
                        a, b)
                nxt = runs[i + 1]
                if prev is not None and lvl > prev and nxt[2] < lvl and i + 1 < len(runs) - 1:
                    add("cycle", f"cycle {_hours(time_s, a, nxt[1])} ({lvl:g} rpm)", a,
                        nxt[1])
            continue
        cuts = np.linspace(0, len(idx), PARTS + 1).round().astype(int)
        for k in range(1, PARTS):
            a, b = int(idx[cuts[k]]), int(idx[cuts[k + 1] - 1]) + 1
            kind = "end" if k == PARTS - 1 else "interior"
            add(kind, f"{kind} {_hours(time_s, a, b)}", a, b)
    out: list[InnerBlock] = []
    for kind in ("cycle", "cool-down", "interior", "end"):
        out += found[kind][-MAX_PER_KIND:]
    return out


def _joined(parts: list[FloatArray]) -> FloatArray:
    return parts[0] if len(parts) == 1 else np.concatenate(parts)


def judge_rows(records: list[Any]) -> tuple[FloatArray | None, FloatArray]:
    """(the first speed column, the time) of `records` concatenated; the speed
    None when a record has none."""
    from compd.offline.channel_kind import ChannelKind, channel_kind

    # one record's columns themselves, not copies (a month at 1 s: 21 MB each)
    time_s = _joined([np.asarray(r.time_s, dtype=np.float64) for r in records])
    name = next((c for c in records[0].columns if channel_kind(c) is ChannelKind.SPEED), None)
    if name is None or any(name not in r.columns for r in records):
        return None, time_s
    return _joined([np.asarray(r.column(name), dtype=np.float64) for r in records]), time_s
