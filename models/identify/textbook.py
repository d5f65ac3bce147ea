"""The textbook thermal model, as a candidate beside compd's own structures.

ARX(2, 3) on two sensors: y(k) + a1 y(k-1) + a2 y(k-2) = Σ_i Σ_{j<3}
b_ij u_i(k-j), least squares on the equation error, no level term, run from
rest at each record's start (the machine starts in equilibrium with its
room, its inputs relative to their first sample). The pair is picked among
the candidate inputs on an inner hold-out: fitted on each record's first
four fifths of the usable rows, simulated from rest, smallest mean absolute
error on the last fifth; then refitted on every usable row.

It is small, its pair is picked on what follows its calibration, and it is
the yardstick compd's figures are measured against
(benchmarks/bench_real_record.py): kept among the candidates, a choice that
is not stable can lean on it (`models.identify.stability`).

A caller that may write the textbook (`compd fit`) hands a `veto`: the
pair is then the best one whose model on every usable row the veto passes
(`compd check`'s warnings: the textbook's free pair often carries two large
DC gains that cancel), tried in order of inner hold-out MAE. Without a veto
the textbook is the free one, as the benchmark's yardstick writes it.

Worked number: 16 temperature candidates give 120 pairs, each one least
squares of 8 columns.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from models.identify.output_error import OeModel
from models.identify.structures import _Data, arx_fit
from models.identify.validate import Pooled, forced_response

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

#: (denominator order, numerator length)
TEXTBOOK_ORDERS = (2, 3)
#: the pair is picked on this last share of each record's usable rows
INNER_FRACTION = 0.2


@dataclass(frozen=True)
class Textbook:
    #: indices of the pair among the candidates
    inputs: tuple[int, ...]
    #: estimated on every usable row
    model: OeModel
    #: residue on each fold's held-out rows, one array per fold and record, in
    #: the order of `models.identify.fold_scores._heldout`
    residuals: tuple[FloatArray, ...]
    #: pooled fit % on the folds' held-out rows (`models.identify.validate.pooled_parts`)
    validation_fit_pct: float


def _data(d: _Data, us: Sequence[FloatArray]) -> _Data:
    return _Data(d.y, list(us), d.seg, d.radius, d.splits, initial=False, usable=d.usable)


def _sim(d: _Data, m: OeModel) -> FloatArray:
    return forced_response(m.nums, m.dens, m.groups, d.us, d.seg)


#: why the textbook's model on a pair must not be written (None: it may be):
#: called with the pair's indices and its estimate on every usable row
Veto = Callable[[tuple[int, ...], OeModel], str | None]


def pick_pair(d: _Data, candidates: Sequence[FloatArray], veto: Veto | None = None
              ) -> tuple[int, ...] | None:
    """The pair (or the single input when there is one) of smallest inner
    hold-out MAE, among those whose model on every usable row `veto` passes
    (None: every pair); None when no pair gives a stable model (or none
    passes)."""
    every = d.every
    inner = np.zeros(d.y.size, dtype=bool)
    for s, e in d.seg.bounds:
        rows = np.flatnonzero(every[s:e]) + s
        if rows.size:
            inner[rows[round(rows.size * (1.0 - INNER_FRACTION)):]] = True
    train = every & ~inner
    na, nb = TEXTBOOK_ORDERS
    ranked: list[tuple[float, tuple[int, ...]]] = []
    k = min(2, len(candidates))
    for pair in itertools.combinations(range(len(candidates)), k):
        dp = _data(d, [candidates[i] for i in pair])
        m = arx_fit(dp, na, nb, train)
        if m is None:
            continue
        sim = _sim(dp, m)
        mae = float(np.mean(np.abs(d.y[inner] - sim[inner])))  # the inner rows only
        del sim
        if math.isfinite(mae):
            ranked.append((mae, pair))
    ranked.sort(key=lambda r: r[0])  # stable: equal MAEs keep the pairs' order
    for _, pair in ranked:
        if veto is None:
            return pair
        m = arx_fit(_data(d, [candidates[i] for i in pair]), na, nb, every)
        if m is not None and veto(pair, m) is None:
            return pair
    return None


def textbook(d: _Data, candidates: Sequence[FloatArray], veto: Veto | None = None
             ) -> Textbook | None:
    """The textbook model on its picked pair (`pick_pair`, `veto`), with its
    residue on the folds of `d` (None: no stable pair, or a fold without a
    stable model)."""
    pair = pick_pair(d, candidates, veto)
    if pair is None:
        return None
    dp = _data(d, [candidates[i] for i in pair])
    na, nb = TEXTBOOK_ORDERS
    blocks: list[FloatArray] = []
    # each fold's held-out rows pooled and let go, not its simulation of every
    # row: a month at 1 s is 21 MB a fold
    pool = Pooled()
    for train, val in d.splits:
        m = arx_fit(dp, na, nb, train)
        if m is None:
            return None
        sim = _sim(dp, m)
        pool.add(d.y[val], sim[val])
        for s, e in d.seg.bounds:
            rows = np.flatnonzero(val[s:e]) + s
            if rows.size:
                blocks.append(np.asarray(d.y[rows] - sim[rows], dtype=np.float64))
        del sim
    final = arx_fit(dp, na, nb, d.every)
    if final is None:
        return None
    return Textbook(pair, final, tuple(blocks), pool.value)
