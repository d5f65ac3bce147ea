"""Output-error fit by Levenberg–Marquardt on compact normal equations, with
shared or per-term denominators and estimated initial conditions.

The criterion is the simulation error over the rows a mask selects (the
training rows of a fold, or every row)::

    min_θ Σ_k w(k) · ( y(k) - ŷ(k) )²,   ŷ = Σ_groups (Σ_{t∈g} A_t u_t + C_g·δ) / B_g + c

- a *group* is a set of inputs sharing one denominator B_g: every input its
  own (the papers' per-term transfer functions) or all in one (a
  multi-input model with one shared denominator);
- the initial conditions of a record that starts warm are estimated with the
  model (``initial=True``): per record, an output level c and per input a
  level v_t added to its relative input (each term relaxing from a steady
  state, the family `models.initial_state` uses: T + 1 well-conditioned
  unknowns where a full state would add fast modes that a held-out first
  block cannot determine);
- stability: B_g is the step-up polynomial of reflection coefficients
  κ = (1 - 1e-12)·tanh(φ) scaled to the pole radius (see
  `models.identify.reflection`), so φ is unconstrained and every pole stays
  within |p| < radius.

This is the project's one output-error fitter: the cross-validated
structures (`models.identify.structures`) call `fit_output_error`, the
greedy per-term search (`models.identify.tf_fit`) calls `refine_oe`, the
same fit with one denominator per input, from rest, on every row.

Why not `scipy.optimize.least_squares`: its bounded 'trf' method takes a dense
SVD of the whole N-row Jacobian at every iteration (90 % of a day-long fit at
1 s). Here each iteration builds J once, reduces it to JᵀJ (p × p, p ≈ 30) and
Jᵀr with two BLAS calls, and solves the damped p × p system: the cost per
iteration is a few filter runs over the record.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from models.identify.arx import fit_pct
from models.identify.blocks import SegFilter, SegLags, row_blocks
from models.identify.reflection import scaled, step_up, to_kappa
from models.identify.segments import Segments

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

_KAPPA_LIM = 1.0 - 1e-12
#: the most a cached simulation (inputs with their levels, each group's output,
#: the output level) may hold, in bytes
CACHE_BYTES = 64 << 20


@dataclass(frozen=True)
class OeModel:
    """Numerators per input, denominators per group, `groups[g]` the inputs
    sharing denominator g; `init` the initial-condition parameters (per
    record: level c, then v_t per input) or empty."""

    nums: tuple[tuple[float, ...], ...]
    dens: tuple[tuple[float, ...], ...]
    groups: tuple[tuple[int, ...], ...]
    init: tuple[float, ...] = ()

    def term_dens(self) -> tuple[tuple[float, ...], ...]:
        """The denominator of each input (a shared one repeated)."""
        out: dict[int, tuple[float, ...]] = {}
        for g, members in enumerate(self.groups):
            for t in members:
                out[t] = self.dens[g]
        return tuple(out[t] for t in range(len(self.nums)))

    @property
    def n_params(self) -> int:
        return sum(len(a) for a in self.nums) + sum(len(b) - 1 for b in self.dens)


class _Problem:
    def __init__(self, y: FloatArray, inputs: Sequence[FloatArray], nbs: Sequence[int],
                 nas: Sequence[int], groups: Sequence[Sequence[int]], seg: Segments,
                 radius: float, initial: bool) -> None:
        self.y, self.us, self.nbs, self.nas = y, list(inputs), list(nbs), list(nas)
        self.groups = [tuple(g) for g in groups]
        self.seg, self.radius, self.initial = seg, radius, initial
        self.n_num = sum(nbs)
        self.n_den = sum(nas)
        self.per_record = 1 + len(self.us)
        self.n_init = len(seg.bounds) * self.per_record if initial else 0
        self.group_of = {t: g for g, m in enumerate(self.groups) for t in m}
        #: the blocks of the last θ simulated (`residual`), kept when the record is
        #: one block: `normal_equations` at the same θ reuses them (each
        #: Levenberg–Marquardt iteration linearises where the last accepted step
        #: was simulated)
        #: the mask last weighed: whether it holds every row, its weights of
        #: every row (None: all 1, or too long to keep) and one past its last
        #: row (nothing after it is simulated)
        self._mask: tuple[BoolArray, bool, FloatArray | None, int] | None = None
        self._cached: tuple[bytes, list[tuple[int, int, list[FloatArray],
                                              list[FloatArray], FloatArray]]] | None = None

    def unpack(self, th: FloatArray) -> tuple[list[FloatArray], list[FloatArray],
                                               list[FloatArray], FloatArray]:
        nums, i = [], 0
        for nb in self.nbs:
            nums.append(th[i:i + nb])
            i += nb
        kappas, dens = [], []
        for na in self.nas:
            k = _KAPPA_LIM * np.tanh(th[i:i + na])
            kappas.append(k)
            dens.append(scaled(step_up(k), self.radius))
            i += na
        return nums, kappas, dens, th[i:]

    def block_inputs(self, init: FloatArray, lo: int, hi: int
                     ) -> tuple[list[FloatArray], FloatArray]:
        """Rows lo … hi-1 of the inputs plus their per-record level v_t, and of
        the output level c."""
        level = np.zeros(hi - lo)
        if not self.initial:
            return [u[lo:hi] for u in self.us], level
        us = [u[lo:hi].copy() for u in self.us]
        for r, (s, e) in enumerate(self.seg.bounds):
            a, b = max(s, lo) - lo, min(e, hi) - lo
            if a >= b:
                continue
            block = init[r * self.per_record:(r + 1) * self.per_record]
            level[a:b] += block[0]
            for t in range(len(us)):
                us[t][a:b] += block[1 + t]
        return us, level

    def blocks(self, th: FloatArray, end: int | None = None
               ) -> Iterator[tuple[int, int, list[FloatArray], list[FloatArray], FloatArray]]:
        """(lo, hi, inputs, each group's output, output level) block by block
        (`models.identify.blocks`: the filters' states carried across), over
        the rows before `end` (default every row): the blocks of `row_blocks`
        of the whole record, the last one cut at `end` and none after it. The
        filters are causal, so a row before `end` is simulated to the same bit
        whatever comes after it."""
        nums, _, dens, init = self.unpack(th)
        firs = [SegFilter(self.seg, a, [1.0]) for a in nums]
        iirs = [SegFilter(self.seg, [1.0], b) for b in dens]
        stop = self.y.size if end is None else end
        for lo, full in row_blocks(self.y.size):
            if lo >= stop:
                return
            hi = min(full, stop)
            us, level = self.block_inputs(init, lo, hi)
            outs = []
            for g, members in enumerate(self.groups):
                v = np.zeros(hi - lo)
                for t in members:
                    v += firs[t](us[t], lo)
                outs.append(iirs[g](v, lo))
            yield lo, hi, us, outs, level

    def _cacheable(self) -> bool:
        """Whether a simulation (inputs with their levels, each group's output,
        the output level) fits within `CACHE_BYTES`; the row weights are kept
        only then too (a longer record streams with a block's memory)."""
        return self.y.size * (len(self.us) + len(self.groups) + 1) * 8 <= CACHE_BYTES

    def _blocks_cached(self, th: FloatArray, end: int
                       ) -> Iterator[tuple[int, int, list[FloatArray], list[FloatArray],
                                           FloatArray]]:
        """`blocks(th, end)`, from the cache when θ and `end` are the ones
        simulated last. A simulation is cached up to `CACHE_BYTES` (a week at
        1 s, four inputs); past that each block is dropped once used, so the
        memory stays that of a block."""
        key = th.tobytes() + end.to_bytes(8, "little")
        if self._cached is not None and self._cached[0] == key:
            yield from self._cached[1]
            return
        if not self._cacheable():
            yield from self.blocks(th, end)
            return
        self._cached = None  # the last one dropped before the next is built
        kept = list(self.blocks(th, end))
        self._cached = (key, kept)
        yield from kept

    def simulate(self, th: FloatArray) -> FloatArray:
        out = np.empty(self.y.size)
        for lo, hi, _, outs, level in self.blocks(th):
            out[lo:hi] = sum(outs) + level
        return out

    def residual(self, th: FloatArray, mask: BoolArray) -> FloatArray:
        """(y - ŷ) · weight, the weight 1 on the rows of `mask` and 0 elsewhere,
        made block by block (neither ŷ nor the weights of every row held).
        Past the last row of `mask` nothing is simulated: the residual there is
        0, as the weight 0 made it."""
        out = np.empty(self.y.size)
        weight, end = self._weights(mask)
        for lo, hi, _, outs, level in self._blocks_cached(th, end):
            out[lo:hi] = self.y[lo:hi] - (sum(outs) + level)
            w = weight(lo, hi)
            if w is not None:
                out[lo:hi] *= w
        out[end:] = 0.0
        return out

    def _weights(self, mask: BoolArray) -> tuple[Callable[[int, int], FloatArray | None], int]:
        """(the weight of rows lo … hi-1 (None: every one is 1, nothing to
        multiply), one past the last row of `mask`), made once per mask (the
        weights of every row kept when they are small enough)."""
        if self._mask is None or self._mask[0] is not mask:
            every = bool(mask.all())
            whole = mask.astype(np.float64) if not every and self._cacheable() else None
            self._mask = (mask, every, whole, counted_end(mask))
        _, every, whole, end = self._mask
        if every:
            return (lambda lo, hi: None), end
        if whole is not None:
            return (lambda lo, hi: whole[lo:hi]), end
        return (lambda lo, hi: mask[lo:hi].astype(np.float64)), end

    def normal_equations(self, th: FloatArray, mask: BoolArray, resid: FloatArray
                         ) -> tuple[FloatArray, FloatArray]:
        """(JᵀJ, Jᵀr) of J = diag(weight) · ∂ŷ/∂θ (`residual`'s weight), accumulated block by block
        (the p × N Jacobian is never built whole: its rows are filled in place
        per block, as building an N × p matrix and fancy-indexing its rows cost
        more than the filters). Nothing past the last row of `mask` is
        filtered: those rows of J are 0, as the weight 0 made them, but for a
        numerator's lagged rows, which are lags of the weighed row (so the
        rows up to nb - 1 past a counted one carry it, as they always have)."""
        nums, kappas, dens, _ = self.unpack(th)
        seg = self.seg
        w_filt = [SegFilter(seg, [1.0], dens[self.group_of[t]]) for t in range(len(self.us))]
        w_lags = [SegLags(seg, nb - 1) for nb in self.nbs]
        v_filt = [SegFilter(seg, [1.0], b) for b in dens]
        v_lags = [SegLags(seg, na) for na in self.nas]
        dpolys, dks = [], []
        for g, na in enumerate(self.nas):
            k = kappas[g]
            dks.append(_KAPPA_LIM * (1.0 - (k / _KAPPA_LIM) ** 2))
            rows = []
            for m in range(na):
                kp, km = k.copy(), k.copy()
                kp[m] += 0.5
                km[m] -= 0.5
                rows.append(scaled(step_up(kp) - step_up(km), self.radius)[1:])
            dpolys.append(rows)
        i_filt = [[SegFilter(seg, nums[t], dens[self.group_of[t]]) for t in range(len(self.us))]
                  for _ in seg.bounds] if self.initial else []
        p = self.n_num + self.n_den + self.n_init
        jtj: FloatArray | None = None
        jtr: FloatArray | None = None
        weight, end = self._weights(mask)
        # each block's Jacobian as wide as the block, nothing filtered past `end`
        # (there the weight 0 makes every row 0) but a numerator's lagged rows,
        # which lag the weighed row and so reach up to nb - 1 rows past it; the
        # blocks after that all zero: left out of the sums
        reach = min(self.y.size, end + max(self.nbs) - 1) if end else 0
        sims = self._blocks_cached(th, end)
        for lo, full in row_blocks(self.y.size):
            if lo >= reach:
                break
            n = 0
            if lo < end:
                _, hi, us, outs, _ = next(sims)
                n = hi - lo
            wb = weight(lo, lo + n)  # None: every row weighs 1 (x · 1.0 is x)
            jt = np.empty((p, full - lo))
            jt[:, n:] = 0.0
            i = 0
            for t, nb in enumerate(self.nbs):
                if n:
                    _weighed(w_filt[t](us[t], lo), wb, jt[i, :n])
                if nb > 1:
                    w_lags[t].feed(jt[i], lo)
                for j in range(1, nb):
                    w_lags[t].shift(j, jt[i + j])
                i += nb
            for g, na in enumerate(self.nas):
                if not n:
                    i += na
                    continue
                v_lags[g].feed(v_filt[g](outs[g], lo), lo)
                d_den = np.zeros((na, full - lo))  # -v(k - m), m = 1 … na, a row each
                for m in range(1, na + 1):
                    np.negative(v_lags[g].shift(m, d_den[m - 1, :n]), out=d_den[m - 1, :n])
                for m in range(na):
                    np.multiply((dpolys[g][m] @ d_den)[:n],
                                dks[g][m] if wb is None else dks[g][m] * wb, out=jt[i, :n])
                    i += 1
            for r, (s, e) in enumerate(seg.bounds if self.initial and n else ()):
                ind = np.zeros(n)
                ind[max(s, lo) - lo:max(min(e, lo + n) - lo, 0)] = 1.0
                _weighed(ind, wb, jt[i, :n])
                i += 1
                for t in range(len(self.us)):
                    _weighed(i_filt[r][t](ind, lo), wb, jt[i, :n])
                    i += 1
            g_blk, r_blk = jt @ jt.T, jt @ resid[lo:full]
            jtj = g_blk if jtj is None else jtj + g_blk
            jtr = r_blk if jtr is None else jtr + r_blk
        if jtj is None or jtr is None:  # a mask of no row: J is 0
            return np.zeros((p, p)), np.zeros(p)
        return jtj, jtr


def counted_end(mask: BoolArray) -> int:
    """One past the last row `mask` counts (0 when it counts none): a fit over
    the rows of `mask` needs nothing simulated after it (the filters are causal)."""
    if mask.size == 0 or not mask.any():
        return 0
    return int(mask.size - np.argmax(mask[::-1]))


def _weighed(x: FloatArray, wb: FloatArray | None, out: FloatArray) -> None:
    """x · wb (x itself when wb is None) written into `out`, a row of the
    Jacobian's block: no temporary array of the block between."""
    if wb is None:
        out[:] = x
    else:
        np.multiply(x, wb, out=out)


def _levenberg_marquardt(prob: _Problem, th0: FloatArray, mask: BoolArray, max_iter: int,
                         tol: float) -> tuple[FloatArray, float, int]:
    """Damped Gauss-Newton on the column-scaled normal equations; stops when
    a step gains less than `tol` of the cost, or none is found."""
    th = th0.copy()
    r = prob.residual(th, mask)
    cost = float(r @ r)
    lam = 1e-3
    it = 0
    for it in range(1, max_iter + 1):  # noqa: B007
        jtj, jtr = prob.normal_equations(th, mask, r)
        d = np.sqrt(np.maximum(np.diag(jtj), 1e-300))
        a = jtj / d[:, None] / d[None, :]
        g = jtr / d
        gain = 0.0
        for _ in range(12):
            try:
                step = np.linalg.solve(a + lam * np.eye(a.shape[0]), g) / d
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            cand = th + step
            rc = prob.residual(cand, mask)
            c_cost = float(rc @ rc)
            if math.isfinite(c_cost) and c_cost < cost:
                gain = (cost - c_cost) / max(cost, 1e-300)
                th, r, cost = cand, rc, c_cost
                lam = max(lam / 3.0, 1e-9)
                break
            lam *= 4.0
        if gain < tol:
            break
    return th, cost, it


def fit_output_error(y: FloatArray, inputs: Sequence[FloatArray],
                     nums: Sequence[Sequence[float]], dens: Sequence[Sequence[float]],
                     groups: Sequence[Sequence[int]], *, mask: BoolArray | None = None,
                     segments: Segments | None = None, radius: float = 1.0,
                     initial: bool = True, init0: Sequence[float] | None = None,
                     max_iter: int = 40, tol: float = 1e-7) -> tuple[OeModel, FloatArray]:
    """Refine (nums per input, dens per group) by output error over the rows
    of `mask` (default all); returns the model and its simulation over the
    whole record (initial conditions included)."""
    prob, th, model = _refined(y, inputs, nums, dens, groups, mask, segments, radius, initial,
                               init0, max_iter, tol)
    return model, prob.simulate(th)


def output_error_model(y: FloatArray, inputs: Sequence[FloatArray],
                       nums: Sequence[Sequence[float]], dens: Sequence[Sequence[float]],
                       groups: Sequence[Sequence[int]], *, mask: BoolArray | None = None,
                       segments: Segments | None = None, radius: float = 1.0,
                       initial: bool = True, init0: Sequence[float] | None = None,
                       max_iter: int = 40, tol: float = 1e-7) -> OeModel:
    """`fit_output_error`'s model alone: no simulation over every record made
    after the fit (a caller that scores the model itself: the structure search,
    its folds and the verdict's refits; one pass over the record and an array
    of every row each)."""
    return _refined(y, inputs, nums, dens, groups, mask, segments, radius, initial, init0,
                    max_iter, tol)[2]


def _refined(y: FloatArray, inputs: Sequence[FloatArray], nums: Sequence[Sequence[float]],
             dens: Sequence[Sequence[float]], groups: Sequence[Sequence[int]],
             mask: BoolArray | None, segments: Segments | None, radius: float, initial: bool,
             init0: Sequence[float] | None, max_iter: int, tol: float
             ) -> tuple[_Problem, FloatArray, OeModel]:
    """(the problem, its refined θ, the model of θ)."""
    y = np.asarray(y, dtype=np.float64)
    us = [np.asarray(u, dtype=np.float64) for u in inputs]
    seg = segments if segments is not None else Segments.single(y.size)
    nbs = [len(a) for a in nums]
    nas = [len(b) - 1 for b in dens]
    if not 0.0 < radius <= 1.0:
        raise ValueError(f"pole radius must be within (0, 1], got {radius!r}")
    if any(na < 1 for na in nas):
        raise ValueError("every denominator needs an order >= 1")
    prob = _Problem(y, us, nbs, nas, groups, seg, radius, initial)
    x0: list[float] = [float(v) for a in nums for v in a]
    for b in dens:
        k = to_kappa(b, radius)
        x0 += [float(v) for v in np.arctanh(np.clip(k / _KAPPA_LIM, -0.999999, 0.999999))]
    if initial:
        x0 += list(init0) if init0 is not None and len(init0) == prob.n_init else \
            [0.0] * prob.n_init
    m = np.ones(y.size, dtype=bool) if mask is None else mask
    th, _, _ = _levenberg_marquardt(prob, np.asarray(x0), m, max_iter, tol)
    n_nums, _, n_dens, init = prob.unpack(th)
    model = OeModel(nums=tuple(tuple(float(v) for v in a) for a in n_nums),
                    dens=tuple(tuple(float(v) for v in b) for b in n_dens),
                    groups=tuple(tuple(g) for g in groups),
                    init=tuple(float(v) for v in init))
    return prob, th, model


@dataclass(frozen=True)
class OeEstimate:
    """Per-term (numerator, denominator), den[0] = 1; fit % on the record."""

    nums: tuple[tuple[float, ...], ...]
    dens: tuple[tuple[float, ...], ...]
    fit_pct: float


def refine_oe(y: FloatArray, inputs: Sequence[FloatArray], nums: Sequence[Sequence[float]],
              dens: Sequence[Sequence[float]], *, max_iter: int = 200, tol: float = 1e-12,
              segments: Segments | None = None, radius: float = 1.0) -> OeEstimate:
    """`fit_output_error` with one denominator per input (the papers'
    per-term transfer functions), every record from rest, every row: the
    refinement of the greedy per-term search (`models.identify.tf_fit`).
    Every pole stays within |p| < `radius` (≤ 1)."""
    y = np.asarray(y, dtype=np.float64)
    seg = segments if segments is not None else Segments.single(y.size)
    if seg.total != y.size:
        raise ValueError(f"segments cover {seg.total} samples, the record has {y.size}")
    groups = [(t,) for t in range(len(nums))]
    model, sim = fit_output_error(y, inputs, nums, dens, groups, segments=seg, radius=radius,
                                  initial=False, max_iter=max_iter, tol=tol)
    return OeEstimate(model.nums, model.term_dens(), fit_pct(y, sim))
