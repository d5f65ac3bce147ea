"""Which sensors: inputs chosen by validation (forward selection with
backward pruning).

A shop's machine has sensors wherever its builder put them, several nearly
collinear, some irrelevant. Choosing them by hand over every triple is what
an engineer does with time to spare; a naive hold-out inside the
calibration window picks worse ones. Here every subset tried is scored by
the forward validation of `models.identify.structures` (run from each
record's start, each held-out block predicted from the rows before it), and
a subset whose estimate its own diagnostics reject
(`models.identify.checks.implausible`) ranks below every plausible one and
is never chosen:

1. forward: add the candidate whose subset validates best, while that gains
   more than `margin_pct` points and the subset has fewer than `max_terms`;
2. after each addition, backward: drop a member (not the one just added)
   when the subset without it validates at least as well minus the margin
   (fewer sensors for the same figure);
3. then swaps: replace one member by one outsider while that gains more
   than `SWAP_GAIN_PCT`. Forward selection alone stops at complementary sensors: on the
   shop machine a column sensor alone validates at -35 % and is never added
   to the spindle sensors, yet bearing + column + room validates at 94.4 %
   where the forward path's bearing + two motor sensors reached 91.5 % (and
   78.5 % instead of 95.4 % on the next day).

At the end, among every subset tried within `margin_pct` of the best, the
one with the fewest inputs wins (then the better validated): a sensor that
adds less than the margin on day 1 is as likely noise on day 2.

Subsets are scored by a cheap screen: the cross-validated Steiglitz–McBride
estimate at its best orders (``flexible``,
`models.identify.structures.order_search_result`, no output-error
refinement) or a fixed ARX(2, 3) (``arx``, `models.identify.screening`),
on the records averaged down to at most `SEARCH_SAMPLES` samples
(blocks of q samples averaged; thermal time constants are minutes to hours,
and the scores only rank subsets): the search costs the same on a day at
1 s as on a day at 60 s. The caller fits every structure on the winner, at
the full rate. Every subset scored is kept, in
order, for the table the command prints.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from models.identify.screening import screen_subset
from models.identify.segments import Segments
from models.identify.structures import DEFAULT_FOLDS, DEFAULT_VALIDATION, order_search_result

FloatArray = npt.NDArray[np.float64]

#: the search scores subsets on records averaged down to this many samples
SEARCH_SAMPLES = 3000
#: rounds of swaps after the forward pass
MAX_SWAP_ROUNDS = 6
#: a swap is taken when it gains more than this (points): smaller steps than
#: the forward margin let the search leave a local optimum (shop seed 1: the
#: forward path's spindle sensors verified at 78.5 % on day 2, 91.8 % after
#: swaps), larger than the day-to-day noise of the figure (at 0.05 an unrelated
#: sensor crept in on seed 5: 82.5 % instead of 91.8 %)
SWAP_GAIN_PCT = 0.25


def decimate(x: FloatArray, seg: Segments, q: int) -> FloatArray:
    """Means of consecutive blocks of `q` samples within each record (a
    record's incomplete last block dropped)."""
    parts = []
    for s, e in seg.bounds:
        m = max(1, (e - s) // q)
        parts.append(x[s:s + m * q].reshape(m, q).mean(axis=1) if (e - s) >= q else x[s:e])
    return np.concatenate(parts)


def _decimated_segments(seg: Segments, q: int) -> Segments:
    return Segments.from_lengths([max(1, n // q) if n >= q else n for n in seg.lengths])


@dataclass(frozen=True)
class Tried:
    inputs: tuple[str, ...]
    validation_fit_pct: float
    step: str
    #: why the subset's model is implausible (never chosen), or ""
    rejected: str = ""

    @property
    def rank(self) -> float:
        """The figure the search compares: -inf for a rejected subset."""
        return -np.inf if self.rejected else self.validation_fit_pct


@dataclass(frozen=True)
class SubsetSearch:
    best: tuple[str, ...]
    best_fit_pct: float
    tried: tuple[Tried, ...]
    #: why even the best subset is implausible (no plausible one found), or ""
    rejected: str = ""


def search_subsets(y: FloatArray, candidates: Mapping[str, FloatArray], *, max_terms: int,
                   na_range: tuple[int, int], nb_range: tuple[int, int],
                   segments: Segments | None = None, radius: float = 1.0,
                   folds: int = DEFAULT_FOLDS, validation: str = DEFAULT_VALIDATION,
                   margin_pct: float = 0.5, screen: str = "flexible",
                   progress: Callable[[int, int], None] | None = None,
                   usable: npt.NDArray[np.bool_] | None = None) -> SubsetSearch:
    """Forward selection with backward pruning (module docstring).
    `screen`: ``flexible`` (the Steiglitz–McBride order search) or ``arx``
    (`models.identify.screening`, a fixed ARX(2, 3)).
    `progress(done, planned)` is called after every subset scored. `usable`:
    the only rows any loss counts (`models.identify.structures.make_data`; an
    averaged block holding a row outside them is outside too)."""
    names = list(candidates)
    if not names:
        raise ValueError("no candidate input")
    if screen not in ("flexible", "arx"):
        raise ValueError(f"unknown screen {screen!r}; known: flexible, arx")
    if max_terms < 1:
        raise ValueError(f"max_terms must be >= 1, got {max_terms}")
    seg = segments if segments is not None else Segments.single(np.asarray(y).size)
    q = max(1, -(-seg.total // SEARCH_SAMPLES))
    if q > 1:
        y = decimate(np.asarray(y, dtype=np.float64), seg, q)
        candidates = {n: decimate(np.asarray(u, dtype=np.float64), seg, q)
                      for n, u in candidates.items()}
        if usable is not None:
            usable = decimate(np.asarray(usable, dtype=np.float64), seg, q) >= 1.0
        seg, radius = _decimated_segments(seg, q), radius ** q
    cache: dict[frozenset[str], Tried] = {}
    tried: list[Tried] = []
    planned = sum(len(names) - i for i in range(min(max_terms, len(names))))
    planned += min(max_terms, len(names)) * max(0, len(names) - max_terms)

    def score(subset: Sequence[str], step: str) -> Tried:
        key = frozenset(subset)
        if key not in cache:
            order = tuple(n for n in names if n in key)
            scorer = screen_subset if screen == "arx" else order_search_result
            val, why = scorer(y, [candidates[n] for n in order], na_range=na_range,
                              nb_range=nb_range, segments=seg, radius=radius, folds=folds,
                              validation=validation, names=order, usable=usable)
            cache[key] = Tried(order, float(val), step, why or "")
            tried.append(cache[key])
            if progress is not None:
                progress(len(tried), max(planned, len(tried)))
        return cache[key]

    current: list[str] = []
    best = Tried((), -np.inf, "")
    while len(current) < min(max_terms, len(names)):
        trials = [score([*current, n], "add") for n in names if n not in current]
        top = max(trials, key=lambda t: (t.rank, t.validation_fit_pct))
        if current and not top.rank > best.rank + margin_pct:
            break
        added = next(n for n in top.inputs if n not in current)
        current, best = list(top.inputs), top
        while len(current) >= 3:
            drops = [score([n for n in current if n != m], "drop")
                     for m in current if m != added]
            fewer = max(drops, key=lambda t: t.rank)
            if not fewer.rank >= best.rank - margin_pct:
                break
            current, best = list(fewer.inputs), fewer
    for _ in range(MAX_SWAP_ROUNDS):
        swaps = [score([n for n in current if n != m] + [o], "swap")
                 for m in current for o in names if o not in current]
        top = max(swaps, key=lambda t: t.rank, default=best)
        if not top.rank > best.rank + SWAP_GAIN_PCT:
            break
        current, best = list(top.inputs), top
    # the simplest within the margin of the best plausible: fewest inputs,
    # then the best; a subset its own diagnostics reject is never chosen
    plausible = [t for t in tried if not t.rejected and np.isfinite(t.rank)]
    if plausible:
        top_rank = max(t.rank for t in plausible)
        near = [t for t in plausible if t.rank >= top_rank - margin_pct]
        best = min(near, key=lambda t: (len(t.inputs), -t.rank))
    else:  # nothing plausible: the best validated, its rejection said by the caller
        best = max(tried, key=lambda t: t.validation_fit_pct, default=best)
    return SubsetSearch(best=best.inputs, best_fit_pct=best.validation_fit_pct,
                        tried=tuple(tried), rejected=best.rejected)
