"""The cost per cycle of three position-dependent axes against one Z offset, with
a named peer measured in the same run.

Models: a value model and a slope model fitted by `compd fit --positions` on
48 h of the ball-screw simulator (the files the daemon would load; the value
from column, screw_bearing, ambient and nut, the slope from nut and
screw_bearing). One axis: the value model alone, as compd writes Z today.
Three axes: three independent copies of the value and the slope model (six
models, each with its own state) and the line evaluated at each axis's
position, c = value + slope · (x - x0) / 1000.

Measured, best of several runs, per cycle over the same inputs:

1. the model step: `CompensationModel.step` for one axis and for three, and
   the peer, `scipy.signal.lfilter` called once per sample per term with its
   `zi` state (and the same input arithmetic), for the same filters; printed:
   three axes / one, and compd / lfilter for each;
2. the pure cycle (`compd.core.cycle.Cycle`: validation, model, fault policy,
   output stage; no I/O): one cycle with the Z model, against three cycles
   each with its value model plus the three slope models stepped beside them.
   The per-axis cycle (one read and one validation for every axis) is not built
   yet, so this three-axis figure is an upper bound of what it will cost; the
   lower bound is one cycle plus the other axes' model steps (their output
   stages not counted). The goal of the issue is ≤ 1.5x.

Run: .venv/bin/python benchmarks/bench_axes.py --cost [--cycles N]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import math
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
from scipy.signal import lfilter

from compd.cli import main as compd
from compd.core.cycle import WRITTEN, Cycle
from compd.infiles import load_model
from compd.offline.cycle_replay import replay_params
from drivers.base import Sample
from drivers.sim.ballscrew import simulate_ballscrew, write_ballscrew_record
from models.compensation import CompensationModel
from models.tf import TransferFunction

VALUE_INPUTS = ("column", "screw_bearing", "ambient", "nut")
SLOPE_INPUTS = ("nut", "screw_bearing")
#: each axis's position read in the cycle (mm) and the reference position
AXIS_POSITIONS_MM = (120.0, 450.0, 780.0)
X0_MM = 0.0
GOAL = 1.5


def _best_of(fn: Callable[[], object], repeats: int) -> float:
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def fit_models(workdir: Path) -> tuple[Path, Path]:
    """The value and slope model files of 48 h of the simulator (seed 1)."""
    record = workdir / "train.csv"
    write_ballscrew_record(record, simulate_ballscrew(48.0, seed=1))
    out = []
    for column, inputs in (("value_um", VALUE_INPUTS), ("slope_um_m", SLOPE_INPUTS)):
        path = workdir / f"{column}.toml"
        argv = ["fit", str(record), "--positions", "--column", column,
                *(a for i in inputs for a in ("--term", i)), "--no-fallbacks", "--json",
                "-o", str(path)]
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            code = compd(argv)
        if code:
            raise SystemExit(f"bench_axes_cost: compd {' '.join(argv)} exited {code}")
        out.append(path)
    return out[0], out[1]


def samples(n: int) -> list[dict[str, float]]:
    """`n` cycles of slowly drifting temperatures (seeded)."""
    rng = np.random.default_rng(0)
    walk = {c: 20.0 + np.cumsum(rng.normal(0.0005, 0.01, n)) for c in VALUE_INPUTS}
    return [{c: float(walk[c][k]) for c in VALUE_INPUTS} for k in range(n)]


def _loaded(path: Path, first: dict[str, float]) -> CompensationModel:
    model = load_model(str(path))
    model.set_references({c: first[c] for c in model.reference_channels})
    return model


def _peer_filters(model: CompensationModel, refs: dict[str, float]
                  ) -> list[tuple[np.ndarray, np.ndarray, list[tuple[str, float, float]], float]]:
    """Each term as (b, a, [(channel, coefficient, reference)], gain) for lfilter."""
    out = []
    for t in model.terms:
        if not isinstance(t.dynamics, TransferFunction):
            raise SystemExit(f"bench_axes_cost: term {t.name!r} is not a transfer function")
        lin = [(c, float(w), refs.get(c, 0.0) if t.relative else 0.0)
               for c, w in t.inputs.items()]
        out.append((np.asarray(t.dynamics.num, dtype=np.float64),
                    np.asarray(t.dynamics.den, dtype=np.float64), lin, float(t.gain)))
    return out


def model_step(value: Path, slope: Path, data: Sequence[dict[str, float]], repeats: int
               ) -> dict[str, float]:
    """Seconds per cycle of compd's step and lfilter's, one axis and three."""
    first = data[0]
    z = _loaded(value, first)
    axes = [(_loaded(value, first), _loaded(slope, first), (x - X0_MM) / 1000.0)
            for x in AXIS_POSITIONS_MM]

    def one() -> list[float]:
        z.reset()
        step = z.step
        return [step(s) for s in data]

    def three() -> list[float]:
        for v, b, _ in axes:
            v.reset()
            b.reset()
        out = []
        for s in data:
            for v, b, dx in axes:
                out.append(v.step(s) + b.step(s) * dx)
        return out

    refs = dict(first)
    zf = _peer_filters(z, refs)
    af = [(_peer_filters(v, refs), _peer_filters(b, refs), dx) for v, b, dx in axes]

    def run_peer(filters: list[tuple[np.ndarray, np.ndarray, list[tuple[str, float, float]],
                                     float]]) -> Callable[[dict[str, float]], float]:
        zis = [np.zeros(max(len(a), len(b)) - 1) for b, a, _, _ in filters]

        def step(s: dict[str, float]) -> float:
            total = 0.0
            for j, (b, a, lin, gain) in enumerate(filters):
                u = np.array([sum(w * (s[c] - r) for c, w, r in lin)])
                y, zis[j] = lfilter(b, a, u, zi=zis[j])
                total += gain * float(y[0])
            return total

        return step

    def peer_one() -> list[float]:
        step = run_peer(zf)
        return [step(s) for s in data]

    def peer_three() -> list[float]:
        steps = [(run_peer(vf), run_peer(bf), dx) for vf, bf, dx in af]
        out = []
        for s in data:
            for v, b, dx in steps:
                out.append(v(s) + b(s) * dx)
        return out

    np.testing.assert_allclose(one(), peer_one(), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(three(), peer_three(), rtol=1e-9, atol=1e-9)
    n = len(data)
    return {"compd 1": _best_of(one, repeats) / n, "compd 3": _best_of(three, repeats) / n,
            "lfilter 1": _best_of(peer_one, max(1, repeats // 2)) / n,
            "lfilter 3": _best_of(peer_three, max(1, repeats // 2)) / n}


def pure_cycle(value: Path, slope: Path, data: Sequence[dict[str, float]], repeats: int
               ) -> dict[str, float]:
    """Seconds per cycle of one `Cycle` with the Z model, and of three cycles with the
    value models and the three slope models beside them (an upper bound)."""
    first = data[0]
    period = load_model(str(value)).period_s
    rows = [{c: Sample(v, k * period) for c, v in s.items()} for k, s in enumerate(data)]

    def cycle_of(model: CompensationModel) -> Cycle:
        return Cycle(replay_params(model, limit_um=500.0, slew_um_s=10.0), model)

    def one() -> None:
        cycle = cycle_of(_loaded(value, first))
        for k, row in enumerate(rows):
            cycle.plan(k * period, row, wall_s=k * period)
            cycle.commit(WRITTEN)

    def three() -> None:
        cycles = [cycle_of(_loaded(value, first)) for _ in AXIS_POSITIONS_MM]
        slopes = [_loaded(slope, first) for _ in AXIS_POSITIONS_MM]
        for k, (row, s) in enumerate(zip(rows, data, strict=True)):
            for cycle, b in zip(cycles, slopes, strict=True):
                cycle.plan(k * period, row, wall_s=k * period)
                cycle.commit(WRITTEN)
                b.step(s)

    n = len(data)
    return {"cycle 1": _best_of(one, repeats) / n, "cycle 3": _best_of(three, repeats) / n}


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=5_000,
                        help="cycles per measurement (default 5000)")
    parser.add_argument("--repeats", type=int, default=5,
                        help="best of this many runs (default 5)")
    args = parser.parse_args(argv)
    if args.cycles < 10 or args.repeats < 1:
        parser.error("--cycles at least 10, --repeats at least 1")
    with tempfile.TemporaryDirectory() as tmp:
        value, slope = fit_models(Path(tmp))
        data = samples(args.cycles)
        steps = model_step(value, slope, data, args.repeats)
        cycles = pure_cycle(value, slope, data, args.repeats)
    us = {k: v * 1e6 for k, v in {**steps, **cycles}.items()}
    print(f"{args.cycles} cycles, best of {args.repeats}; one axis: the value model (Z); "
          f"three axes: value + slope each, the line at x = "
          f"{', '.join(f'{x:g}' for x in AXIS_POSITIONS_MM)} mm")
    print("model step, µs per cycle")
    print(f"  compd  one axis {us['compd 1']:8.2f}   three axes {us['compd 3']:8.2f}   "
          f"ratio {steps['compd 3'] / steps['compd 1']:.2f}x")
    print(f"  scipy.signal.lfilter per sample, zi: one axis {us['lfilter 1']:8.2f}   "
          f"three axes {us['lfilter 3']:8.2f}   ratio "
          f"{steps['lfilter 3'] / steps['lfilter 1']:.2f}x")
    print(f"  lfilter / compd: one axis {steps['lfilter 1'] / steps['compd 1']:.1f}x, "
          f"three axes {steps['lfilter 3'] / steps['compd 3']:.1f}x")
    ratio = cycles["cycle 3"] / cycles["cycle 1"]
    low = (cycles["cycle 1"] + steps["compd 3"] - steps["compd 1"]) / cycles["cycle 1"]
    print("pure cycle (compd.core.cycle.Cycle, no I/O), µs per cycle")
    print(f"  one axis {us['cycle 1']:8.2f}   three axes as three cycles + slopes "
          f"{us['cycle 3']:8.2f}   ratio {ratio:.2f}x (upper bound)")
    print(f"  one cycle + the other axes' model steps (their output stages not counted): "
          f"ratio {low:.2f}x (lower bound)")
    print(f"  goal ≤ {GOAL:g}x: the upper bound {'meets' if ratio <= GOAL else 'misses'} it, "
          f"the lower bound {'meets' if low <= GOAL else 'misses'} it; the per-axis cycle "
          f"lies between")
    return 0
