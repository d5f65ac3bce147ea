"""Identification speed, each against the straightforward way in the same run.

1. ARX order search: orders 1-4 for three terms (4 · 4³ = 256 structures) on
   24 h of 1 s data (86,400 samples), against the naive per-structure loop
   (its own regression matrix and numpy.linalg.lstsq each time).
2. Output-error refinement of one structure (four per-term transfer
   functions, 86,400 samples, the same start): Levenberg–Marquardt on compact
   normal equations (`models.identify.output_error`, the project's one
   output-error fitter) against scipy's bounded 'trf' on the same residual
   and the same stable parametrisation (a dense SVD of the N-row Jacobian per
   iteration; what the greedy search used before it was made one fitter).
3. The whole structure choice of `compd fit` (four terms, 86,400 samples,
   orders 1-4): cross-validated selection (`models.identify.structures`)
   against the greedy output-error search it replaced (`tf_fit.fit_tf_terms`).
4. Subset search over 17 candidates up to 3 terms on 10,000 samples of the
   shop machine (`models.identify.subsets`): subsets scored per second
   against scoring a subset the straightforward way (the greedy per-term
   output-error search on it), timed on a few subsets.

Run: OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_fit.py [--quick]
(--quick skips the slow straightforward peers of 3 and 4)."""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np

from models.identify.arx import naive_select, select_arx, simulate_common


def bench_arx() -> None:
    n = 86_400
    rng = np.random.default_rng(0)
    us = [np.repeat(rng.uniform(-3, 3, n // h + 1), h)[:n] for h in (1800, 2700, 3600)]
    y = simulate_common((1.0, -0.998), ((0.05, -0.03), (0.01,), (-0.02, 0.01)), us)
    y = y + 0.5 * rng.standard_normal(n)
    t0 = time.perf_counter()
    select_arx(y, us, (1, 4), (1, 4))
    fast = time.perf_counter() - t0
    t0 = time.perf_counter()
    naive_select(y, us, (1, 4), (1, 4))
    naive = time.perf_counter() - t0
    print(f"orders 1-4, 3 terms, {n} samples: one QR + column subsets {fast:.3f} s, "
          f"naive per-structure lstsq loop {naive:.3f} s, ratio {naive / fast:.1f}x "
          f"({'under' if fast < 2.0 else 'OVER'} the 2 s target)")


def _day() -> tuple[np.ndarray, list[np.ndarray]]:
    from drivers.sim.offline import simulate
    from drivers.sim.programs import spectrum

    cols = simulate(spectrum(seed=3, hours=24.0), seed=3, period_s=1.0)
    us = [cols[c] - cols[c][0] for c in ("bearing", "motor", "column", "ambient")]
    return cols["dz_um"], us


def bench_refinement(y: np.ndarray, us: list[np.ndarray]) -> None:
    from models.identify.arx import fit_pct, refit
    from models.identify.output_error import fit_output_error

    start = refit(y, us, 3, [3] * len(us))
    dens = [start.den] * len(us)
    groups = [(t,) for t in range(len(us))]
    t0 = time.perf_counter()
    _, sim = fit_output_error(y, us, start.nums, dens, groups, initial=False, max_iter=40,
                              tol=1e-6)
    fast = time.perf_counter() - t0
    t0 = time.perf_counter()
    slow_fit = _scipy_trf(y, us, start.nums, dens, 40)
    slow = time.perf_counter() - t0
    print(f"OE refinement, 4 per-term TFs (3/3), {y.size} samples, 40 iterations at most: "
          f"compact LM {fast:.2f} s (fit {fit_pct(y, sim):.2f} %), scipy trf "
          f"{slow:.2f} s (fit {slow_fit:.2f} %), ratio {slow / fast:.1f}x")


def _scipy_trf(y: np.ndarray, us: list[np.ndarray], nums: Sequence[Sequence[float]],
               dens: Sequence[Sequence[float]], max_nfev: int) -> float:
    """Fit % of scipy's bounded 'trf' on the per-term output error from rest
    (κ boxed within ±1, finite-difference Jacobian): the straightforward peer."""
    from scipy.optimize import least_squares

    from models.identify.arx import fit_pct
    from models.identify.reflection import scaled, step_up, to_kappa
    from models.identify.segments import Segments

    seg = Segments.single(y.size)
    nbs = [len(a) for a in nums]
    nas = [len(b) - 1 for b in dens]

    def simulate(th: np.ndarray) -> np.ndarray:
        out, i = np.zeros(y.size), 0
        for u, nb, na in zip(us, nbs, nas, strict=True):
            num, kappa = th[i:i + nb], th[i + nb:i + nb + na]
            out += seg.filter(num, scaled(step_up(kappa), 1.0), u)
            i += nb + na
        return out

    x0: list[float] = []
    lo: list[float] = []
    for a, b in zip(nums, dens, strict=True):
        x0 += [float(v) for v in a] + [float(v) for v in to_kappa(b)]
        lo += [-np.inf] * len(a) + [-1.0 + 1e-9] * (len(b) - 1)
    hi = [-v if np.isfinite(v) else np.inf for v in lo]
    res = least_squares(lambda th: y - simulate(th), np.asarray(x0), bounds=(lo, hi),
                        method="trf", x_scale="jac", max_nfev=max_nfev)
    return float(fit_pct(y, simulate(res.x)))


class _Counter:
    """Counts the calls of a module-level function (monkeypatched)."""

    def __init__(self, module: object, name: str) -> None:
        self.module, self.name, self.calls = module, name, 0
        self.original = getattr(module, name)

    def __enter__(self) -> _Counter:
        def counted(*args: object, **kwargs: object) -> object:
            self.calls += 1
            return self.original(*args, **kwargs)

        setattr(self.module, self.name, counted)
        return self

    def __exit__(self, *exc: object) -> None:
        setattr(self.module, self.name, self.original)


def bench_selection(y: np.ndarray, us: list[np.ndarray], quick: bool) -> None:
    from models.identify import structures, tf_fit

    t0 = time.perf_counter()
    with _Counter(structures, "arx_fit") as a, _Counter(structures, "fit_output_error") as o, \
            _Counter(structures, "_ridge") as r:
        sel = structures.select_structure(y, us, na_range=(1, 4), nb_range=(1, 4))
    fast = time.perf_counter() - t0
    fitted = a.calls + o.calls + r.calls
    print(f"structure choice, 4 terms, {y.size} samples, orders 1-4: cross-validated "
          f"{fast:.2f} s ({sel.chosen.structure}, validation "
          f"{sel.chosen.validation_fit_pct:.2f} %, fit {sel.chosen.fit_pct:.2f} %; "
          f"{fitted} structures fitted ({a.calls} least squares, {o.calls} output error, "
          f"{r.calls} ridge), {fitted / fast:.1f} per second)")
    if quick:
        return
    t0 = time.perf_counter()
    with _Counter(tf_fit, "refine_oe") as g:
        old = tf_fit.fit_tf_terms(y, us, (1, 4), (1, 4))
    slow = time.perf_counter() - t0
    print(f"  the greedy output-error search it replaced: {slow:.2f} s (fit "
          f"{old.oe.fit_pct:.2f} %; {g.calls} output-error fits + one ARX order search, "
          f"{g.calls / slow:.2f} per second), time ratio {slow / fast:.1f}x, structures "
          f"per second ratio {(fitted / fast) / (g.calls / slow):.0f}x "
          f"({'under' if fast < 10.0 else 'OVER'} the 10 s target for the whole fit)")


def bench_subsets(quick: bool) -> None:
    from drivers.sim.shop import SENSORS, simulate_shop
    from models.identify.subsets import search_subsets
    from models.identify.tf_fit import fit_tf_terms

    cols = simulate_shop(24.0, period_s=8.64, seed=1)
    y = cols["dz_um"]
    cands = {n: cols[n] - cols[n][0] for n in SENSORS}
    cands["spindle_rpm"] = cols["spindle_rpm"]
    t0 = time.perf_counter()
    found = search_subsets(y, cands, max_terms=3, na_range=(1, 4), nb_range=(1, 4))
    fast = time.perf_counter() - t0
    rate = len(found.tried) / fast
    print(f"subset search, 17 candidates, up to 3 terms, {y.size} samples: {fast:.1f} s "
          f"({'within' if fast <= 60.0 else 'OVER'} the 60 s target), {len(found.tried)} "
          f"subsets, {rate:.2f} per second; best {' + '.join(found.best)} "
          f"({found.best_fit_pct:.2f} %)")
    if quick:
        return
    sample = [t.inputs for t in found.tried[:: max(1, len(found.tried) // 3)]][:3]
    t0 = time.perf_counter()
    for subset in sample:
        fit_tf_terms(y, [cands[n] for n in subset], (1, 4), (1, 4))
    slow_rate = len(sample) / (time.perf_counter() - t0)
    print(f"  straightforward scoring (greedy per-term OE search per subset, {len(sample)} "
          f"timed): {slow_rate:.3f} subsets per second, ratio {rate / slow_rate:.1f}x")


def main() -> None:
    import sys

    quick = "--quick" in sys.argv[1:]
    bench_arx()
    y, us = _day()
    bench_refinement(y, us)
    bench_selection(y, us, quick)
    bench_subsets(quick)


if __name__ == "__main__":
    main()
