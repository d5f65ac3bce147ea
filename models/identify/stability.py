"""How stable a choice among validated candidates is, and a hedge when it
is not.

Each candidate (inputs and structure) leaves a residue on the rows each
fold held out. Those rows are cut into blocks (every fold's block halved,
`SUB_BLOCKS`); the figures here are

- **fold wins**: on how many blocks each candidate has the smallest squared
  error;
- **resampled wins** (the stability): the blocks drawn `DRAWS` times with
  replacement (a fixed seed: the same records give the same figure), each
  draw won by the candidate with the smallest summed squared error; each
  candidate's share of the draws.

A choice that wins most draws is bet on. One that does not is a choice
among candidates the data do not tell apart, and picking the best of a
noisy table is what over-fits: the candidates leading the draws are then
averaged, each weighted by its share (`hedge`). A weighted sum of
difference-equation models is again one: its terms are the members' terms,
numerators scaled by the weights, and the daemon steps them as any other.

Worked number: two candidates, four blocks with squared errors (1, 1, 1, 5)
and (2, 2, 2, 1): the first wins three blocks of four, yet every draw
holding the fourth block goes to the second, 1 - (3/4)^4 = 68 % of them: a
choice that wins most blocks by a little and loses one by much is not
stable.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

#: each held-out block is cut into this many parts before resampling
SUB_BLOCKS = 2
#: resampled draws of the blocks
DRAWS = 1000
#: the choice is bet on when it wins at least this share of the draws
STABLE_SHARE = 0.6
#: a hedge takes the leading candidates until their shares sum to this …
HEDGE_COVER = 0.8
#: … and at most this many
HEDGE_MEMBERS = 3
SEED = 20240530


def block_errors(residuals: Sequence[FloatArray], parts: int = SUB_BLOCKS) -> FloatArray:
    """Sum of squares of each residue block cut into `parts`."""
    out: list[float] = []
    for r in residuals:
        for piece in np.array_split(np.asarray(r, dtype=np.float64), parts):
            if piece.size:
                out.append(float(np.sum(piece ** 2)))
    return np.asarray(out, dtype=np.float64)


@dataclass(frozen=True)
class Stability:
    #: share of the resampled draws each candidate wins
    shares: tuple[float, ...]
    #: share of the blocks each candidate wins alone
    block_wins: tuple[float, ...]
    blocks: int


def stability(errors: Sequence[FloatArray], draws: int = DRAWS, seed: int = SEED) -> Stability:
    """`errors[c]`: candidate c's squared error per block (the same blocks
    for every candidate)."""
    e = np.stack([np.asarray(x, dtype=np.float64) for x in errors])
    n_c, n_b = e.shape
    if n_b == 0:
        raise ValueError("no held-out block to judge the candidates on")
    e = np.where(np.isfinite(e), e, 1e300)  # a diverged candidate loses every block
    per_block = np.bincount(np.argmin(e, axis=0), minlength=n_c) / n_b
    rng = np.random.default_rng(seed)
    picks = rng.integers(0, n_b, size=(draws, n_b))
    counts = np.zeros((draws, n_b))
    np.add.at(counts, (np.arange(draws)[:, None], picks), 1.0)
    totals = counts @ e.T
    wins = np.bincount(np.argmin(totals, axis=1), minlength=n_c) / draws
    return Stability(tuple(float(x) for x in wins), tuple(float(x) for x in per_block), n_b)


def hedge(shares: Sequence[float], chosen: int, stable_share: float = STABLE_SHARE,
          cover: float = HEDGE_COVER, members: int = HEDGE_MEMBERS
          ) -> list[tuple[int, float]]:
    """(candidate, weight) of the model to write: the chosen one alone when it
    wins at least `stable_share` of the draws; otherwise the candidates
    leading the draws (until their shares reach `cover`, at most `members`),
    weighted by their shares."""
    if shares[chosen] >= stable_share:
        return [(chosen, 1.0)]
    order = sorted(range(len(shares)), key=lambda i: -shares[i])
    picked: list[int] = []
    total = 0.0
    for i in order:
        if len(picked) >= members or total >= cover or shares[i] <= 0.0:
            break
        picked.append(i)
        total += shares[i]
    if not picked:
        return [(chosen, 1.0)]
    return [(i, shares[i] / total) for i in picked]
