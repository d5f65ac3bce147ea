"""The cost per cycle of three position-dependent axes against one Z offset, with
a named peer measured in the same run.

Models: a value model and a slope model fitted by `compd fit --positions` on
48 h of the ball-screw simulator (the files the daemon would load; the value
from column, screw_bearing, ambient and nut, the slope from nut and
screw_bearing). One axis: the value model alone, as compd writes Z today.
Three axes: three independent copies of the value and the slope model (six
models, each with its own state) and the line evaluated at each axis's
position, c = value + slope · (x - x0) / 1000.

Measured as CPU time (`time.process_time`, which a loaded machine moves less
than wall time), per cycle over the same inputs, in interleaved rounds (each
round measures everything once, in turn), the median of each printed:

1. the model step: `CompensationModel.step` for one axis and for three, and
   the peer, `scipy.signal.lfilter` called once per sample per term with its
   `zi` state (and the same input arithmetic), for the same filters, checked
   equal to compd's; printed: three axes / one, and lfilter / compd;
2. the pure cycle (`compd.core.cycle.Cycle` plan + commit, no I/O) built from
   a config as the daemon builds it (`params_from_config`): the Z offset alone
   (the value model as [model]), against the same config with X, Y and Z each
   written as value + slope (``[output.axes.<axis>]``, parameter form; six
   more models); each write read back as written;
3. the whole daemon (`compd.runtime.daemon.Daemon`, checkpoint every 20,
   recorder on, JSON logs to /dev/null) in lockstep over
   `compd.testing.MemoryDriver` on a `compd.testing.SteppedClock`, the same
   two configs, after a warm-up.

Before timing, the runs are checked: both configs write the same Z offset,
and the three-axes runs write every axis's value and slope. The goal of the
issue is three axes ≤ 1.5x one.

Run: .venv/bin/python benchmarks/bench_axes.py --cost [--cycles N] [--repeats N]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import io
import math
import os
import statistics
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
from scipy.signal import lfilter

from compd.cli import main as compd
from compd.config.loader import LoadedConfig, load_config
from compd.core.cycle import WRITTEN, Cycle, params_from_config
from compd.core.plan import Plan
from compd.infiles import load_model
from compd.testing import MemoryDriver, SteppedClock
from drivers.base import Sample
from drivers.sim.ballscrew import simulate_ballscrew, write_ballscrew_record
from models.compensation import CompensationModel
from models.tf import TransferFunction

VALUE_INPUTS = ("column", "screw_bearing", "ambient", "nut")
SLOPE_INPUTS = ("nut", "screw_bearing")
#: each axis's position read in the cycle (mm) and the reference position
AXIS_POSITIONS_MM = (120.0, 450.0, 780.0)
X0_MM = 0.0
#: the axes written as parameters in the three-axes config
AXES = ("x", "y", "z")
GOAL = 1.5
#: the daemon's cycles before its timing starts (start-up, first checkpoint)
WARMUP = 200


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


def model_step(value: Path, slope: Path, data: Sequence[dict[str, float]]
               ) -> dict[str, Callable[[], float]]:
    """compd's step and lfilter's, one axis and three, checked equal: each a run
    over `data` that returns its CPU seconds per cycle."""
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

    def timed(fn: Callable[[], object]) -> Callable[[], float]:
        def run() -> float:
            t0 = time.process_time()
            fn()
            return (time.process_time() - t0) / n
        return run

    return {"compd 1": timed(one), "compd 3": timed(three), "lfilter 1": timed(peer_one),
            "lfilter 3": timed(peer_three)}


def config_text(value: Path, slope: Path, period_s: float, *, axes: bool) -> str:
    """A Modbus config with the ball-screw channels and `value` as [model] (the Z offset);
    `axes`: X, Y and Z written as value + slope besides (``[output.axes.<axis>]``)."""
    channels = "".join(
        f'[channels.{c}]\naddress = {{ kind = "input", address = {i}, type = "int16", '
        f'scale = 0.1 }}\nunit = "degC"\nrange = [-20.0, 150.0]\n\n'
        for i, c in enumerate(VALUE_INPUTS))
    text = f"""[machine]
name = "bench"
period_s = {period_s!r}
time_scale = 1.0

[controller]
protocol = "modbus"
endpoint = "modbus://127.0.0.1:1"
timeout_s = 0.4

{channels}[model]
file = "{value}"

[output]
offset = {{ kind = "holding", address = 0, type = "float32" }}
heartbeat = {{ kind = "holding", address = 2, type = "uint16" }}
status = {{ kind = "holding", address = 3, type = "uint16" }}
limit_um = 500.0
slew_um_s = 10.0
"""
    if axes:
        text += 'axes_status = { kind = "holding", address = 4, type = "uint16" }\n'
        for k, axis in enumerate(AXES):
            base = 32 + 6 * k
            text += f"""
[output.axes.{axis}]
reference = {{ kind = "holding", address = {base}, type = "int32", scale = 0.0001 }}
value = {{ kind = "holding", address = {base + 2}, type = "int32", scale = 0.1 }}
slope = {{ kind = "holding", address = {base + 4}, type = "int32" }}
reference_mm = {X0_MM!r}
value_limit_um = 500.0
slope_limit_um_m = 500.0
slew_um_s = 10.0
slope_slew_um_m_s = 10.0
model = {{ file = "{value}" }}
slope_model = {{ file = "{slope}" }}
"""
    return text + """
[faults]
hold_s = 600.0

[state]
dir = "state"
checkpoint_every = 20

[recorder]
commit_every = 10
"""


def _rows(data: Sequence[dict[str, float]], period_s: float) -> list[dict[str, Sample]]:
    return [{c: Sample(v, k * period_s) for c, v in s.items()} for k, s in enumerate(data)]


def pure_cycle(config: Path, rows: Sequence[dict[str, Sample]]) -> tuple[float, list[Plan]]:
    """CPU seconds per cycle of `Cycle` plan + commit built from `config` as the
    daemon builds it (`params_from_config`), each write read back as written;
    and the last plans (for the checks)."""
    cfg = load_config(config)
    cycle = Cycle(params_from_config(cfg), cfg.model, cfg.shadow)
    offset, names = cycle.params.offset_name, cycle.axes.names
    # the controller's registers as read back: 0 until written (as `MemoryDriver`'s)
    written = dict.fromkeys((offset, *names), 0.0)
    period = cfg.period_s
    plans: list[Plan] = []
    t0 = time.process_time()
    for k, row in enumerate(rows):
        axes = {n: written[n] for n in names} if names else None
        plan = cycle.plan(k * period, row, written[offset], wall_s=k * period,
                          axes_readback=axes)
        cycle.commit(WRITTEN)
        written.update(plan.writes)
        if k >= len(rows) - 3:
            plans.append(plan)
    return (time.process_time() - t0) / len(rows), plans


def whole_daemon(config: Path, data: Sequence[dict[str, float]]
                 ) -> tuple[float, MemoryDriver]:
    """CPU seconds per cycle of the daemon in lockstep over `MemoryDriver` (after
    `WARMUP` cycles), the driver (for the checks)."""
    from compd.faces.telemetry import configure_logging

    with open(os.devnull, "w") as devnull:
        configure_logging(json=True, level="info", stream=devnull)
        return asyncio.run(_daemon_cycles(load_config(config), data))


async def _daemon_cycles(cfg: LoadedConfig, data: Sequence[dict[str, float]]
                         ) -> tuple[float, MemoryDriver]:
    from compd.runtime.daemon import Daemon
    from compd.runtime.sdnotify import Notifier

    clock = SteppedClock(period_s=cfg.period_s)

    def wall() -> float:
        return 1.7e9 + clock()

    # every output the config writes (with [output.axes]: each axis's parameters)
    driver = MemoryDriver(data[0], tuple(cfg.outputs), wall=wall)
    daemon = Daemon(cfg, driver=driver, notifier=Notifier(None), clock=clock, wall=wall,
                    sleep=clock.sleep)
    task = asyncio.create_task(daemon.run())
    await clock.cycle_done(1)
    t0 = 0.0
    for k in range(1, len(data)):
        if k == WARMUP:
            t0 = time.process_time()
        for c, v in data[k].items():
            driver.set(c, v)
        clock.tick()
        await clock.cycle_done(k + 1)
    cpu = time.process_time() - t0
    daemon.request_stop()
    if await task != 0:
        raise SystemExit("bench_axes_cost: the daemon did not stop cleanly")
    return cpu / (len(data) - WARMUP), driver


def _check(one: Sequence[Plan], three: Sequence[Plan], d1: MemoryDriver, d3: MemoryDriver,
           axis_names: Sequence[str]) -> None:
    """Both configs write the same Z offset from valid inputs, the three-axes one
    every axis's value (the Z offset's, on its grid) and slope, finite and non-zero;
    in the daemon, the one-axis run writes no axis and the three-axes run every one."""
    for a, b in zip(one, three, strict=True):
        if a.writes["offset"] != b.writes["offset"] or not a.inputs_valid:
            raise SystemExit("bench_axes_cost: the Z offset differs between the configs")
        missing = [n for n in axis_names if n.endswith(("_value", "_slope"))
                   and not (math.isfinite(b.writes.get(n, math.nan)) and b.writes[n] != 0.0)]
        if missing:
            raise SystemExit(f"bench_axes_cost: the three-axes cycle did not write {missing}")
        # each axis's value is the Z model's (the same model file), on the 0.1 µm grid
        off = [a for a in AXES if abs(b.writes[f"{a}_comp_value"] - b.writes["offset"]) > 0.1]
        if off:
            raise SystemExit(f"bench_axes_cost: the value of {off} is not the Z offset's")
    if d1.outputs["offset"] != d3.outputs["offset"] or d1.outputs["offset"] == 0.0:
        raise SystemExit("bench_axes_cost: the daemons' Z offsets differ or are 0")
    written = set().union(*d3.writes)
    if not set(axis_names) <= written or not set(axis_names).isdisjoint(set().union(*d1.writes)):
        raise SystemExit("bench_axes_cost: the daemons did not write the axes as configured")


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=5_000,
                        help="cycles per measurement (default 5000)")
    parser.add_argument("--repeats", type=int, default=7,
                        help="rounds, each measuring everything once in turn; the median "
                             "of each is printed (default 7)")
    args = parser.parse_args(argv)
    if args.cycles < 2 * WARMUP or args.repeats < 1:
        parser.error(f"--cycles at least {2 * WARMUP}, --repeats at least 1")
    with tempfile.TemporaryDirectory() as tmp:
        where = Path(tmp)
        value, slope = fit_models(where)
        data = samples(args.cycles)
        period = load_model(str(value)).period_s
        rows = _rows(data, period)

        def config(axes: bool) -> Path:
            # each run its own folder: a daemon's state (checkpoint, record) is its own
            run = Path(tempfile.mkdtemp(dir=where))
            path = run / "compd.toml"
            path.write_text(config_text(value, slope, period, axes=axes), encoding="utf-8")
            return path

        runs = model_step(value, slope, data)
        _, one_plans = pure_cycle(config(False), rows)
        _, three_plans = pure_cycle(config(True), rows)
        _, d1 = whole_daemon(config(False), data)
        _, d3 = whole_daemon(config(True), data)
        names = [f"{a}_comp_{p}" for a in AXES for p in ("reference", "value", "slope")]
        _check(one_plans, three_plans, d1, d3, names)
        runs |= {"cycle 1": lambda: pure_cycle(config(False), rows)[0],
                 "cycle 3": lambda: pure_cycle(config(True), rows)[0],
                 "daemon 1": lambda: whole_daemon(config(False), data)[0],
                 "daemon 3": lambda: whole_daemon(config(True), data)[0]}
        got: dict[str, list[float]] = {k: [] for k in runs}
        for _ in range(args.repeats):
            for k, run in runs.items():
                got[k].append(run())
    med = {k: statistics.median(v) for k, v in got.items()}
    us = {k: v * 1e6 for k, v in med.items()}

    def ratio(key: str) -> float:
        return med[f"{key} 3"] / med[f"{key} 1"]

    def spread(key: str) -> str:
        # each round's own ratio (its two runs back to back, under the same load)
        r = [b / a for a, b in zip(got[f"{key} 1"], got[f"{key} 3"], strict=True)]
        return f"rounds {min(r):.2f}-{max(r):.2f}x, their median {statistics.median(r):.2f}x"

    print(f"{args.cycles} cycles, CPU time, median of {args.repeats} interleaved rounds; "
          f"one axis: the Z offset (value model); three axes: the Z offset and X, Y, Z "
          f"each as value + slope (parameter form)")
    print("model step, µs per cycle")
    print(f"  compd  one axis {us['compd 1']:8.2f}   three axes {us['compd 3']:8.2f}   "
          f"ratio {ratio('compd'):.2f}x")
    print(f"  scipy.signal.lfilter per sample, zi: one axis {us['lfilter 1']:8.2f}   "
          f"three axes {us['lfilter 3']:8.2f}   ratio {ratio('lfilter'):.2f}x")
    print(f"  lfilter / compd: one axis {med['lfilter 1'] / med['compd 1']:.1f}x, "
          f"three axes {med['lfilter 3'] / med['compd 3']:.1f}x")
    print("pure cycle (compd.core.cycle.Cycle plan + commit, no I/O), µs per cycle")
    print(f"  one axis {us['cycle 1']:8.2f}   three axes {us['cycle 3']:8.2f}   "
          f"ratio {ratio('cycle'):.2f}x ({spread('cycle')})")
    print(f"whole daemon, lockstep over MemoryDriver (after {WARMUP} cycles), µs per cycle")
    print(f"  one axis {us['daemon 1']:8.2f}   three axes {us['daemon 3']:8.2f}   "
          f"ratio {ratio('daemon'):.2f}x ({spread('daemon')})")
    for key, what in (("cycle", "the pure cycle"), ("daemon", "the whole daemon")):
        print(f"goal ≤ {GOAL:g}x: {what} {'meets' if ratio(key) <= GOAL else 'misses'} it")
    return 0
