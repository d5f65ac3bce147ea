"""Initial filter states of a compensation model estimated from a record.

A record rarely starts with the machine cold: a model started at rest at its
first sample predicts nothing of the heat already in the machine, and a
verification score of such a replay says more about the start than about the
model. System-identification tools compare a model with data after
estimating its initial state; so does `compd replay --init estimate`.

The output of a linear term started from a state z0 is its response from
rest plus a free response linear in z0. A full state has as many unknowns as
the term's order, and on a short window its slow free responses extrapolate
badly (four third-order terms on three hours of a cold 12 h record lost
six points against the rest start). So the state is sought in the family
a warm machine actually holds: each transfer-function term at steady state
for an unknown input level v_t (`TransferFunction.steady_state`), relaxing
from there while its relative input starts at 0, plus one output level c
(the persistent share of the heat already in the machine):

    ŷ(k) = ŷ_rest(k) + c + Σ_t v_t · R_t(k),   R_t = relaxation from steady_state(1)

c and v_t are found by least squares on the first `window` samples of the
measured displacement (default the first half); the relaxations then run
through the whole record. On a 48 h record split in two (the second half
replayed with the per-term model fitted on the first) this gives 85.15 %, as the run
continuous from the start of the whole record, where the rest start gives
-319 % (benchmarks/bench_calibration.py). Grey-box and MBOTV terms keep
their rest state (only c covers them).

Worked number: a first-order term 0.1/(1 - 0.9 q⁻¹) (DC gain 1) at steady
state for v = 1 and then fed 0 gives 0.9, 0.81, 0.729, … .
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from models.compensation import CompensationModel
from models.tf import TransferFunction

FloatArray = npt.NDArray[np.float64]

#: default share of the record used to estimate the initial state
#: (shop machine seed 7, day 2: first quarter 83.7 %, first half 93.3 %, the
#: whole record 94.1 %; the 48 h split 85.00 / 85.10 / 85.10 %)
DEFAULT_WINDOW_FRACTION = 0.5
#: a window longer than this is reduced block by block to its Gram matrix
GRAM_ROWS = 1 << 17


@dataclass(frozen=True)
class InitialState:
    """The estimated output level `offset_um`, each TF term's input level
    (its steady state at the first sample) and the added response over the
    record (to add to the replay from rest)."""

    offset_um: float
    levels: dict[str, float]
    response: FloatArray


def relaxation(tf: TransferFunction, n: int) -> FloatArray:
    """The output of `tf` started at steady state for input 1, then fed 0
    (its state is restored afterwards)."""
    saved = tf.export_state()
    tf.steady_state(1.0)
    out = tf.simulate(np.zeros(n))
    tf.import_state(saved)
    return out


def relaxation_basis(model: CompensationModel, gains: Sequence[FloatArray | float],
                     n: int) -> tuple[FloatArray, list[str]]:
    """[1 | R_t1 | R_t2 …] (n rows) and the term of each column after the
    constant. `gains[t]`: term t's gain (a number or a series)."""
    relaxing: list[tuple[str, TransferFunction, FloatArray | float]] = []
    for term, g in zip(model.terms, gains, strict=True):
        dyn = term.dynamics
        if isinstance(dyn, TransferFunction) and dyn.order > 0 and math.isfinite(dyn.dc_gain):
            relaxing.append((term.name, dyn, g))
    # filled column by column: a list of columns stacked was the basis twice over (a
    # month at 1 s: 100 MB more at the replay's peak)
    basis = np.empty((n, 1 + len(relaxing)))
    basis[:, 0] = 1.0
    for j, (_, dyn, g) in enumerate(relaxing, start=1):
        basis[:, j] = relaxation(dyn, n)
        basis[:, j] *= np.asarray(g, dtype=np.float64)
    return basis, [name for name, _, _ in relaxing]


def estimate_initial_state(residual: FloatArray, basis: FloatArray, names: Sequence[str],
                           window: int) -> InitialState:
    """Least squares of `residual` (measured - replay from rest) on the
    basis over the first `window` rows (column-scaled, tiny singular values
    cut: terms with nearly equal slow poles relax alike)."""
    n = residual.size
    w = max(1, min(int(window), n))
    if w <= GRAM_ROWS:
        a = basis[:w]
        scale = np.sqrt(np.mean(a ** 2, axis=0))
        scale[scale == 0.0] = 1.0
        theta, *_ = np.linalg.lstsq(a / scale, residual[:w], rcond=1e-10)
        theta = theta / scale
    else:
        theta = _gram_lstsq(basis, residual, w)
    levels = {name: float(v) for name, v in zip(names, theta[1:], strict=True)}
    return InitialState(offset_um=float(theta[0]), levels=levels,
                        response=np.asarray(basis @ theta, dtype=np.float64))


def _gram_lstsq(basis: FloatArray, residual: FloatArray, w: int) -> FloatArray:
    """`estimate_initial_state`'s least squares over a long window through the
    scaled basis's Gram matrix, summed over blocks of `GRAM_ROWS` rows (the
    window's scaled copy and lstsq's own were a month's basis twice over);
    the tiny singular values cut as before (rcond 1e-10 on the basis is
    1e-20 on its Gram matrix)."""
    k = basis.shape[1]
    gram, rhs, sumsq = np.zeros((k, k)), np.zeros(k), np.zeros(k)
    for lo in range(0, w, GRAM_ROWS):
        a = basis[lo:min(w, lo + GRAM_ROWS)]
        gram += a.T @ a
        rhs += a.T @ residual[lo:min(w, lo + GRAM_ROWS)]
        sumsq += np.einsum("ij,ij->j", a, a)
    scale = np.sqrt(sumsq / w)
    scale[scale == 0.0] = 1.0
    theta, *_ = np.linalg.lstsq(gram / scale[:, None] / scale[None, :], rhs / scale,
                                rcond=1e-20)
    return np.asarray(theta / scale, dtype=np.float64)


def default_window(n: int, fraction: float = DEFAULT_WINDOW_FRACTION) -> int:
    """Samples used to estimate the initial state: the first `fraction` of
    the record, at least 10 (or all of a shorter record)."""
    return min(n, max(10, round(n * fraction)))
