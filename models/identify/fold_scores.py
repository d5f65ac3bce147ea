"""How an estimate is scored on the folds: simulated from each record's
start (initial conditions fitted on the training rows when they are
estimated), its fit pooled over the held-out rows (`_score`), or over
held-out records (`_score_holdout`); the residue it leaves on rows it was not
calibrated on (`_heldout`), and its fit on every usable row (`_final_fit`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from models.identify.arx import fit_pct
from models.identify.fold_data import _Data
from models.identify.output_error import OeModel, counted_end
from models.identify.segments import Segments
from models.identify.validate import Pooled, forced_response, pooled_fit, with_initial
from models.initial_state import DEFAULT_WINDOW_FRACTION

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]



def _simulate(d: _Data, m: OeModel, train: BoolArray, y: FloatArray, us: Sequence[FloatArray],
              seg: Segments, rows: BoolArray | None = None) -> FloatArray:
    """`m` from rest at every record's start, plus the initial conditions
    fitted on `train` rows when they are estimated. With `rows` (the rows the
    caller reads), nothing is simulated past the last of them or of `train`
    (a forward fold's held-out block ends before the record does): the rows
    before are the same to the bit, those after are 0."""
    end = None if rows is None else max(counted_end(rows), counted_end(train))
    forced = forced_response(m.nums, m.dens, m.groups, us, seg, end)
    if not d.initial:
        return forced
    return with_initial(y, forced, m.nums, m.dens, m.groups, seg, train, end)


def _heads(seg: Segments, size: int) -> BoolArray:
    """The rows of each held-out record's first part (`DEFAULT_WINDOW_FRACTION`,
    one row at least), on which its initial conditions are estimated."""
    head = np.zeros(size, dtype=bool)
    for s, e in seg.bounds:
        head[s:s + max(1, round((e - s) * DEFAULT_WINDOW_FRACTION))] = True
    return head


def _score_holdout(d: _Data, m: OeModel | None) -> tuple[float, list[float]]:
    """Held-out records: initial conditions from each one's first half,
    the rest scored."""
    assert d.holdout is not None
    if m is None:
        return -math.inf, []
    y, us, seg = d.holdout
    head = _heads(seg, y.size)
    sim = _simulate(d, m, head, y, us, seg)
    return pooled_fit(y, [sim], [~head]), [fit_pct(y[~head], sim[~head])]


def _score(d: _Data, fit_on: Callable[[BoolArray], OeModel | None]) -> tuple[float, list[float]]:
    if d.holdout is not None:
        return _score_holdout(d, fit_on(d.every))
    pool = Pooled()  # each fold's held-out rows added and let go
    per: list[float] = []
    for train, val in d.splits:
        m = fit_on(train)
        if m is None:
            return -math.inf, []
        sim = _simulate(d, m, train, d.y, d.us, d.seg, val)
        y_v, sim_v = d.y[val], sim[val]
        del sim
        pool.add(y_v, sim_v)
        per.append(fit_pct(y_v, sim_v))
    return pool.value, per


@dataclass(frozen=True)
class _Heldout:
    rms: float = math.nan
    displacement_rms: float = math.nan
    residuals: tuple[FloatArray, ...] = ()


def _heldout(d: _Data, models: Sequence[OeModel | None]) -> _Heldout:
    """The residue over the held-out rows of every fold, each model trained
    without them: its RMS (what compensation would leave there), the RMS of
    the displacement from each record's first row (what no compensation
    leaves), and the residue itself per contiguous block. nan when a fold has
    no model."""
    if any(m is None for m in models):
        return _Heldout()
    if d.holdout is not None:
        y, us, seg = d.holdout
        head = _heads(seg, y.size)
        pairs = [(models[0], head, ~head)]
    else:
        y, us, seg = d.y, d.us, d.seg
        pairs = [(m, t, v) for m, (t, v) in zip(models, d.splits, strict=True)]
    err = disp = 0.0
    count = 0
    blocks: list[FloatArray] = []
    for m, train, val in pairs:
        assert m is not None
        sim = _simulate(d, m, train, y, us, seg, val)
        # the residue on the held-out rows in row order, once (a month at 1 s
        # holds four fifths of its rows out, 17 MB an array): made in place in
        # the simulation, then taken; each record's block of residue is its
        # slice of it
        resid = np.subtract(y, sim, out=sim)[val]
        del sim
        err += float(np.sum(resid ** 2))
        # the displacement from each record's first row on the held-out rows,
        # made in place in their copy (no array of the first rows beside it)
        dev = y[val]
        at = 0
        for s, e in seg.bounds:
            k = int(val[s:e].sum())
            dev[at:at + k] -= y[s]
            at += k
        disp += float(np.sum(dev ** 2))
        del dev
        count += int(val.sum())
        at = 0
        for s, e in seg.bounds:
            k = int(val[s:e].sum())
            if k:
                blocks.append(resid[at:at + k])
            at += k
    if count == 0:
        return _Heldout()
    return _Heldout(math.sqrt(err / count), math.sqrt(disp / count), tuple(blocks))


class _Replay:
    """Hands out already-trained fold models in fold order (for `_score`)."""

    def __init__(self, models: list[OeModel | None]) -> None:
        self._it = iter(models)

    def __call__(self, _train: BoolArray) -> OeModel | None:
        return next(self._it)


def _final_fit(d: _Data, m: OeModel) -> float:
    every = d.every
    sim = _simulate(d, m, every, d.y, d.us, d.seg)
    if d.usable is None:  # every row: the arrays themselves, not copies
        return fit_pct(d.y, sim)
    return fit_pct(d.y[every], sim[every])
