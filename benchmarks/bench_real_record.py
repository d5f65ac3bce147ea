"""The yardstick of the whole calibration procedure, selection included, on a
real machine's record.

The vendored record (tests/data/fl_thermal/calibration.csv, 27.8 h at 15 s:
4 h at 1250, 2500 and 3750 rpm each followed by 4 h at rest, then 5000 rpm
from 24.1 h) is cut into held-out blocks of every kind of "later":

- forward splits: calibrate on the rows before 12.1, 16.1 and 20.1 h and
  score everything after (faster speeds than calibrated);
- whole heat/cool cycles from the middle: the 2500 rpm cycle (8.1-16.1 h)
  and the 3750 rpm cycle (16.1-24.1 h), each an interior speed once the
  rest is calibrated;
- cool-downs: from the bottom speed (1250 rpm, 4.1-8.1 h) and from the
  top speed that cools in these rows (3750 rpm, 20.1-24.1 h);
- the end: the 5000 rpm step (24.1-27.8 h), calibrated on all before it.

For each block the calibration is the rest of the rows: the held-out rows
are masked from every loss (``args.exclude_rows`` of `compd fit`, see
`compd.offline.fit_terms.usable_rows`), never cut: every model runs
continuously from the record's start, from rest (the machine starts at room
temperature, and a daemon started on it knows no displacement), and is
scored only on the held-out rows. Per block and channel, in one run:

- compd: ``compd fit --candidates 't*_degC' --candidates spindle_rpm
  --max-terms 3`` (the command's own code: inputs, structure, orders and its
  hedge against an unstable choice), the written model stepped as the
  daemon steps it;
- the textbook baseline: ARX(2,3), y(k) + a1 y(k-1) + a2 y(k-2) =
  Σ_i Σ_{j<3} b_ij u_i(k-j), by least squares on the equation error, no
  level term, the two temperature sensors picked among all 120 pairs on an
  inner hold-out (the last fifth of the calibration rows, the pair fitted
  on the four fifths before), then refitted on every calibration row and
  run from rest.

compd's model is what `compd fit` writes without ``--force``: a model its
last word refuses (`compd.offline.fit_judge`, inner held-out blocks of the
calibration rows) counts as no compensation, and compd's choice before that
word is scored beside it, with each setting of the word (`RULES`) computed
from the inner blocks' table fit reports, all in the same run (``--save``
keeps every cell).

Printed: MAE and RMS (µm) of each on the held-out rows, the ratio of compd's
MAE to the baseline's, and per channel the geometric mean and the worst of
that ratio over every block (the goals: worst ≤ 1, geometric mean ≤ 0.7),
with the stability `compd fit` reports for its choice. A default is chosen
on this whole table, never on one family of blocks.

``--shop 1,2,3,4,5``: the same protocol on the simulated shop machine
(`compd sim --machine shop --hours 48 --period-s 60`), day 2 held out.

Run: OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_real_record.py
[--blocks NAME,NAME…] [--shop SEEDS] [ch1 ch3 …]
"""

from __future__ import annotations

import contextlib
import io
import itertools
import json
import math
import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
import numpy.typing as npt
from scipy.signal import lfilter

from compd.cli import build_parser
from compd.offline.fit_judge import AVERAGE, LEAN_WEIGHT, TEXTBOOK

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

RECORD = Path(__file__).resolve().parent.parent / "tests" / "data" / "fl_thermal" / \
    "calibration.csv"
#: more `compd fit` arguments (--fit-args), to judge another default on the whole table
FIT_ARGS: list[str] = []
CHANNELS = ("ch1_um", "ch2_um", "ch3_um", "ch4_um", "ch5_um")
ARX_NA, ARX_NB = 2, 3
#: the baseline's pair is picked on the last INNER_FRACTION of the calibration rows
INNER_FRACTION = 0.2
#: the program's edges in these rows, h (speed changes at 0.129 + 4 k)
EDGE = 0.129
END = math.inf

#: held-out blocks: name, kind, (from, until) in hours of the record
BLOCKS: tuple[tuple[str, str, float, float], ...] = (
    ("after 12.1 h", "forward", 12.0 + EDGE, END),
    ("after 16.1 h", "forward", 16.0 + EDGE, END),
    ("after 20.1 h", "forward", 20.0 + EDGE, END),
    ("cycle 2500", "cycle", 8.0 + EDGE, 16.0 + EDGE),
    ("cycle 3750", "cycle", 16.0 + EDGE, 24.0 + EDGE),
    ("cool 1250", "cool-down", 4.0 + EDGE, 8.0 + EDGE),
    ("cool 3750", "cool-down", 20.0 + EDGE, 24.0 + EDGE),
    ("end 5000", "end", 24.0 + EDGE, END),
)


def read(path: Path) -> dict[str, FloatArray]:
    with path.open() as f:
        head = f.readline().strip().split(",")
    data = np.loadtxt(path, delimiter=",", skiprows=1)
    return {name: data[:, i] for i, name in enumerate(head)}


def figures(y: FloatArray, sim: FloatArray) -> tuple[float, float]:
    r = y - sim
    return float(np.mean(np.abs(r))), float(np.sqrt(np.mean(r ** 2)))


# --- compd's own procedure, through the command's code ------------------------------

@dataclass(frozen=True)
class Choice:
    sim: FloatArray
    what: str
    seconds: float
    stability: float
    #: compd's choice before the verdict of the inner held-out blocks
    #: (`compd.offline.fit_judge`), run from rest; `sim` when it wrote that
    before: FloatArray | None = None
    #: what the verdict wrote: compd's choice, the textbook, or no model
    verdict: str = ""
    #: the fit's own textbook ARX(2,3) from rest (None: none it could write)
    fit_textbook: FloatArray | None = None
    #: the verdict as fit said it (`compd.offline.fit_judge.Verdict.as_dict`)
    judge: dict[str, Any] | None = None


def _unjudged(args: object, n: int, key: str = "unjudged_terms") -> FloatArray | None:
    """The sum of compd's choice's terms before the verdict (`key`: or the
    fit's textbook's), from rest."""
    from models.identify.segments import Segments
    from models.identify.validate import forced_response

    terms = getattr(args, key, None)
    if not terms:
        return None
    seg = Segments.single(n)
    total = np.zeros(n)
    for t in terms:
        total += forced_response([t.num], [t.den], [(0,)], [t.u], seg)
    return total


def compd_choice(record: Path, out: str, held: BoolArray, model: Path) -> Choice:
    """`compd fit` on the whole record with `held` masked from every loss,
    the written model replayed from rest over the whole record."""
    import dataclasses

    from compd.commands.fit import fit_request
    from compd.errors import CompdError
    from compd.infiles import load_model
    from compd.offline.fit import fit_model, save_model
    from compd.offline.fit_request import FitRun
    from compd.offline.model_replay import replay_model
    from compd.offline.records import read_record
    from models.errors import ModelError

    # no --force: a model fit refuses is not written, and the daemon then
    # compensates nothing (scored as no compensation)
    argv = ["fit", str(record), "--column", out, "--candidates", "t*_degC", "--candidates",
            "spindle_rpm", "--max-terms", "3", "-o", str(model), "--json", "--no-fallbacks",
            *FIT_ARGS]
    model.unlink(missing_ok=True)
    request = dataclasses.replace(fit_request(build_parser().parse_args(argv)),
                                  exclude_rows=held)
    run = FitRun.of(request)
    err = io.StringIO()
    t0 = time.perf_counter()
    failed: str | None = None
    try:
        with contextlib.redirect_stderr(err):
            fit = fit_model(request, run)
    except (CompdError, ModelError) as exc:
        failed = str(exc)
    took = time.perf_counter() - t0
    rows = read_record(str(record))
    before = _unjudged(run, held.size)
    extra = {"fit_textbook": _unjudged(run, held.size, "judged_textbook_terms"),
             "judge": run.judge_verdict}
    if failed is not None:
        if "nothing written" in failed or "not written" in failed:
            none = np.full(held.size, rows.column(out)[0])
            return Choice(none, f"no model: {failed}", took, math.nan, before, "no model",
                          **extra)
        return Choice(np.full(held.size, math.nan), f"fit failed: {failed}", took, math.nan,
                      before, **extra)
    save_model(fit.model, model, record.name)
    sel = fit.info[0]["selection"]
    what = f"{' + '.join(fit.search_chosen or [t['name'] for t in fit.info])} " \
        f"({sel['structure']})"
    stab = sel.get("stability", {}).get("share", math.nan)
    verdict = sel.get("judge", {}).get("chosen", "")
    sim = replay_model(load_model(str(model)), rows)
    return Choice(np.asarray(sim, dtype=np.float64), what, took, float(stab), before, verdict,
                  **extra)


# --- the textbook baseline, plain numpy --------------------------------------------

def arx_fit(y: FloatArray, us: list[FloatArray], train: BoolArray
            ) -> tuple[FloatArray, list[FloatArray]] | None:
    """(a, b per input) by least squares on the equation error over the rows
    whose lags are all training rows; no level term. None if unstable."""
    lag = max(ARX_NA, ARX_NB - 1)
    ok = train.copy()
    ok[:lag] = False
    for d in range(1, lag + 1):
        ok[d:] &= train[:-d]
    rows = np.flatnonzero(ok)
    cols = [-y[rows - i] for i in range(1, ARX_NA + 1)]
    for u in us:
        cols += [u[rows - j] for j in range(ARX_NB)]
    theta, *_ = np.linalg.lstsq(np.stack(cols, axis=1), y[rows], rcond=None)
    a = np.concatenate([[1.0], theta[:ARX_NA]])
    if np.any(np.abs(np.roots(a)) >= 1.0):
        return None
    coef: FloatArray = np.asarray(theta, dtype=np.float64)
    return a, [coef[ARX_NA + k * ARX_NB:ARX_NA + (k + 1) * ARX_NB] for k in range(len(us))]


def arx_simulate(fit: tuple[FloatArray, list[FloatArray]], us: list[FloatArray]) -> FloatArray:
    """From rest at the record's start."""
    a, bs = fit
    sim = np.zeros(us[0].size)
    for b, u in zip(bs, us, strict=True):
        sim = sim + lfilter(b, a, u)
    return np.asarray(sim, dtype=np.float64)


def textbook(d: dict[str, FloatArray], out: str, held: BoolArray) -> tuple[FloatArray, str]:
    """The baseline's prediction over the whole record and its pair."""
    y = d[out]
    temps = [c for c in d if c.startswith("t") and c.endswith("_degC")]
    rel = {t: d[t] - d[t][0] for t in temps}
    cal = np.flatnonzero(~held)
    cut = cal[round(cal.size * (1.0 - INNER_FRACTION))]
    inner_train = ~held & (np.arange(y.size) < cut)
    inner_score = ~held & (np.arange(y.size) >= cut)
    best: tuple[float, tuple[str, ...]] | None = None
    for pair in itertools.combinations(temps, 2):
        us = [rel[p] for p in pair]
        f = arx_fit(y, us, inner_train)
        if f is None:
            continue
        mae = float(np.mean(np.abs((y - arx_simulate(f, us))[inner_score])))
        if math.isfinite(mae) and (best is None or mae < best[0]):
            best = (mae, pair)
    if best is None:
        return np.full(y.size, math.nan), "no stable pair"
    us = [rel[p] for p in best[1]]
    f = arx_fit(y, us, ~held)
    if f is None:
        return np.full(y.size, math.nan), f"{' + '.join(best[1])} unstable on all rows"
    return arx_simulate(f, us), " + ".join(best[1])


# --- the table ---------------------------------------------------------------------

#: compd's prediction mixed with the baseline's, (1 - w) · compd + w · textbook: what
#: `compd.offline.fit_hedge.TEXTBOOK_SHARE` = w writes when the run's share is 0 (the
#: fit's textbook is this baseline), so one run judges those defaults too
MIXES = (0.25, 0.5)


@dataclass(frozen=True)
class Cell:
    block: str
    channel: str
    compd: tuple[float, float]
    base: tuple[float, float]
    none_mae: float
    choice: Choice
    pair: str
    #: MAE of each of MIXES
    mixed: tuple[float, ...] = ()
    #: MAE and RMS of compd's choice before the inner blocks' verdict
    before: tuple[float, float] = (math.nan, math.nan)
    #: MAE of the fit's own textbook (nan: none it could write)
    fit_tb: float = math.nan
    #: MAE of compd's choice before the verdict averaged with the fit's own
    #: textbook (`compd.offline.fit_judge.LEAN_WEIGHT`; nan: no textbook)
    fit_avg: float = math.nan

    @property
    def ratio(self) -> float:
        return self.compd[0] / self.base[0]

    @property
    def ratio_before(self) -> float:
        return self.before[0] / self.base[0]


def run(record: Path, d: dict[str, FloatArray], blocks: list[tuple[str, str, float, float]],
        channels: list[str], tmp: Path) -> list[Cell]:
    hours = d["time_s"] / 3600.0
    cells: list[Cell] = []
    for name, _kind, lo, hi in blocks:
        held = (hours >= lo) & (hours < hi)
        for out in channels:
            y = d[out]
            choice = compd_choice(record, out, held, tmp / f"{out}.toml")
            base, pair = textbook(d, out, held)
            mixed = tuple(figures(y[held], ((1 - w) * choice.sim + w * base)[held])[0]
                          for w in MIXES)
            after = figures(y[held], choice.sim[held])
            before = after if choice.before is None else figures(y[held], choice.before[held])
            fit_tb = math.nan if choice.fit_textbook is None else \
                figures(y[held], choice.fit_textbook[held])[0]
            fit_avg = math.nan if choice.fit_textbook is None or choice.before is None else \
                figures(y[held], ((1 - LEAN_WEIGHT) * choice.before
                                  + LEAN_WEIGHT * choice.fit_textbook)[held])[0]
            cell = Cell(name, out, after,
                        figures(y[held], base[held]), float(np.mean(np.abs(y[held] - y[0]))),
                        choice, pair, mixed, before, fit_tb, fit_avg)
            cells.append(cell)
            print(f"{name} {out}: compd {choice.what}, stability {choice.stability:.2f}, "
                  f"{choice.seconds:.1f} s: MAE {cell.compd[0]:.2f} µm (written: "
                  f"{choice.verdict or '?'}; compd's choice before the verdict "
                  f"{cell.before[0]:.2f}); textbook {pair}: "
                  f"{cell.base[0]:.2f} µm (ratio {cell.ratio:.2f}); no compensation "
                  f"{cell.none_mae:.2f} µm", flush=True)
    return cells


def worst(xs: list[float]) -> float:
    """The largest finite ratio (a block where the textbook found no stable
    model has none)."""
    ok = [x for x in xs if math.isfinite(x)]
    return max(ok) if ok else math.nan


def geo(xs: list[float]) -> float:
    ok = [x for x in xs if math.isfinite(x) and x > 0.0]
    return math.exp(float(np.mean(np.log(ok)))) if ok else math.nan


def print_table(cells: list[Cell], blocks: list[str], channels: list[str]) -> None:
    short = [c.removesuffix("_um") for c in channels]
    print("\nMAE on the held-out rows, µm: compd / textbook ARX(2,3) (ratio)")
    print("| block | " + " | ".join(short) + " |")
    print("|---|" + "---|" * len(channels))
    at = {(c.block, c.channel): c for c in cells}
    for b in blocks:
        row = [at[(b, ch)] for ch in channels if (b, ch) in at]
        print(f"| {b} | " + " | ".join(f"{c.compd[0]:.2f} / {c.base[0]:.2f} ({c.ratio:.2f})"
                                       for c in row) + " |")
    print("\nper channel over every block: ratio of compd's MAE (and RMS) to the textbook's")
    print("| channel | geometric mean MAE | worst MAE | geometric mean RMS | worst RMS | "
          "blocks ≤ 1 | mean stability | fit s (mean) |")
    print("|---|---|---|---|---|---|---|---|")
    for ch, s in zip(channels, short, strict=True):
        mine = [c for c in cells if c.channel == ch]
        r = [c.ratio for c in mine]
        rr = [c.compd[1] / c.base[1] for c in mine]
        stab = [c.choice.stability for c in mine if math.isfinite(c.choice.stability)]
        print(f"| {s} | {geo(r):.2f} | {worst(r):.2f} | {geo(rr):.2f} | {worst(rr):.2f} | "
              f"{sum(x <= 1.0 for x in r)} of {len(r)} | "
              f"{(float(np.mean(stab)) if stab else math.nan):.2f} | "
              f"{float(np.mean([c.choice.seconds for c in mine])):.1f} |")
    print("\nbefore / after the verdict of the inner held-out blocks (compd.offline."
          "fit_judge): ratio of MAE to the textbook's, and cells worse than no compensation")
    print("| channel | geometric mean before | after | worst before | after | "
          "worse than none before | after | written: choice / average / textbook / none |")
    print("|---|---|---|---|---|---|---|---|")
    for ch, s in zip(channels, short, strict=True):
        mine = [c for c in cells if c.channel == ch]
        rb, ra = [c.ratio_before for c in mine], [c.ratio for c in mine]
        wb = sum(c.before[0] > c.none_mae for c in mine)
        wa = sum(c.compd[0] > c.none_mae for c in mine)
        kinds = [sum(c.choice.verdict == v for c in mine)
                 for v in ("compd's choice", AVERAGE, "textbook", "no model")]
        print(f"| {s} | {geo(rb):.2f} | {geo(ra):.2f} | {worst(rb):.2f} | {worst(ra):.2f} | "
              f"{wb} of {len(mine)} | {wa} of {len(mine)} | "
              f"{' / '.join(str(k) for k in kinds)} |")
    variants(cells, channels)
    print("\nmixed with the textbook, (1 - w) · compd + w · textbook: ratio of MAE to the "
          "textbook's, geometric mean / worst")
    print("| channel | " + " | ".join(f"w = {w:g}" for w in MIXES) + " |")
    print("|---|" + "---|" * len(MIXES))
    for ch, s in zip(channels, short, strict=True):
        mine = [c for c in cells if c.channel == ch]
        mixed = []
        for k in range(len(MIXES)):
            r = [c.mixed[k] / c.base[0] for c in mine]
            mixed.append(f"{geo(r):.2f} / {worst(r):.2f}")
        print(f"| {s} | " + " | ".join(mixed) + " |")
    every = [c.ratio for c in cells]
    print(f"{sum(not math.isfinite(x) for x in every)} blocks without a stable textbook "
          "model (left out of the ratios)")
    print(f"all: geometric mean {geo(every):.3f}, worst {worst(every):.2f}, "
          f"{sum(x <= 1.0 for x in every)} of {len(every)} at or below the textbook, "
          f"{sum(c.compd[0] > c.none_mae for c in cells)} worse than no compensation")
    prior = [c.ratio_before for c in cells]
    print(f"before the verdict: geometric mean {geo(prior):.3f}, worst {worst(prior):.2f}, "
          f"{sum(x <= 1.0 for x in prior)} of {len(prior)} at or below the textbook, "
          f"{sum(c.before[0] > c.none_mae for c in cells)} worse than no compensation")


#: the verdict's settings judged on the whole table: (tie, worse ratio, end,
#: lean ratio, lean to) of `compd.offline.fit_judge.decide`; inf tie: compd's
#: choice unless unsafe; end: the inner end block judges only the textbook in
#: compd's choice's place ("textbook", `compd.offline.fit_judge.FORWARD_KINDS`),
#: every candidate ("every"), or is left out ("none"); lean: compd's choice
#: gives way to the average with the textbook (or the textbook) when its
#: geometric mean MAE over the inner blocks exceeds the textbook's by this
#: ratio (inf: never)
RULES: tuple[tuple[float, float, str, float, str], ...] = (
    (math.inf, 1.5, "textbook", math.inf, AVERAGE),
    (math.inf, 1.5, "every", math.inf, AVERAGE),
    (math.inf, 1.1, "textbook", math.inf, AVERAGE),
    (math.inf, 1.5, "textbook", 0.8, AVERAGE),
    (math.inf, 1.5, "textbook", 1.0, AVERAGE),
    (math.inf, 1.5, "textbook", 1.25, AVERAGE),
    (math.inf, 1.5, "textbook", 1.0, TEXTBOOK),
    (math.inf, 1.5, "textbook", 1.25, TEXTBOOK),
    (math.inf, 1.5, "textbook", 0.0, AVERAGE),
    (math.inf, 1.5, "textbook", 0.0, TEXTBOOK))


def variants(cells: list[Cell], channels: list[str]) -> None:
    """The verdict again with other settings, from the MAE per inner block
    that fit said: what would have been written (compd's choice before the
    verdict, the fit's own textbook, or nothing) scored on the held-out rows."""
    from compd.offline.fit_judge import COMPD, FORWARD_KINDS, decide

    print("\nthe verdict's settings (tie, worse-than-none ratio, end, lean ratio, lean to): "
          "ratio of MAE to the textbook's, geometric mean / worst, and cells worse than no "
          "compensation")
    print("| channel | " + " | ".join(f"{t:g}, {w:g}, end: {e}, lean {lr:g} to "
                                     f"{'average' if lt == AVERAGE else lt}"
                                     for t, w, e, lr, lt in RULES) + " |")
    print("|---|" + "---|" * len(RULES))
    for ch in [*channels, "all"]:
        mine = [c for c in cells if ch in ("all", c.channel)]
        out = []
        for tie, worse_r, ends, lean_r, lean_to in RULES:
            r: list[float] = []
            bad = 0
            for c in mine:
                j = c.choice.judge
                mae = c.before[0]
                if j is not None:
                    kinds = j.get("kinds") or [b.split()[0] for b in j["blocks"]]
                    keep = [i for i, k in enumerate(kinds) if ends != "none" or k != "end"]
                    table = {k: [math.nan if vs[i] is None else vs[i] for i in keep]
                             for k, vs in j["mae_um"].items()}
                    pick = decide(table, [j["blocks"][i] for i in keep], j["floor_um"],
                                  tie=tie, worse_ratio=worse_r,
                                  kinds=[kinds[i] for i in keep],
                                  forward=FORWARD_KINDS if ends == "textbook" else frozenset(),
                                  lean_ratio=lean_r, lean_to=lean_to
                                  ).chosen if keep else COMPD
                    # an average fit refused (compd check) leaves compd's choice
                    refused = any(r.startswith("not averaged") for r in j.get("reasons", []))
                    if pick == TEXTBOOK and math.isfinite(c.fit_tb):
                        mae = c.fit_tb
                    elif pick == AVERAGE and math.isfinite(c.fit_avg) and not refused:
                        mae = c.fit_avg
                    elif pick not in (COMPD, TEXTBOOK, AVERAGE):
                        mae = c.none_mae
                r.append(mae / c.base[0])
                bad += mae > c.none_mae
            out.append(f"{geo(r):.2f} / {worst(r):.2f} / {bad}")
        print(f"| {ch.removesuffix('_um')} | " + " | ".join(out) + " |")


def main() -> None:
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("channels", nargs="*", help="ch1 … ch5 (default: every one)")
    parser.add_argument("--blocks", default="",
                        help="comma-separated block names (default: every one: "
                             + ", ".join(b[0] for b in BLOCKS) + ")")
    parser.add_argument("--shop", default="", metavar="SEEDS",
                        help="instead: the simulated shop machine, day 2 held out, per seed "
                             "(comma-separated, e.g. 1,2,3,4,5)")
    parser.add_argument("--textbook-share", type=float, default=None, metavar="W",
                        help="the textbook ARX's share of compd's model "
                             "(compd.offline.fit_hedge.TEXTBOOK_SHARE; default: its own)")
    parser.add_argument("--save", default="", metavar="JSON",
                        help="write each cell's figures and fit's verdict to this file")
    parser.add_argument("--fit-args", default="", metavar="ARGS",
                        help="more compd fit arguments, e.g. '--orders 1-4' (another default "
                             "judged on the whole table)")
    args = parser.parse_args()
    FIT_ARGS.extend(args.fit_args.split())
    if args.textbook_share is not None:
        from compd.offline import fit_hedge

        fit_hedge.TEXTBOOK_SHARE = args.textbook_share
    if args.shop:
        shop([int(s) for s in args.shop.split(",")])
        return
    channels = [c if c.endswith("_um") else f"{c}_um" for c in args.channels] or list(CHANNELS)
    wanted = [b.strip() for b in args.blocks.split(",") if b.strip()]
    blocks = [b for b in BLOCKS if not wanted or b[0] in wanted]
    if wanted and len(blocks) != len(wanted):
        parser.error(f"--blocks {args.blocks!r}: known blocks are "
                     + ", ".join(b[0] for b in BLOCKS))
    d = read(RECORD)
    print(f"record {RECORD.name}: {d['time_s'].size} rows every "
          f"{d['time_s'][1] - d['time_s'][0]:g} s, {d['time_s'][-1] / 3600:.1f} h; blocks: "
          + "; ".join(f"{n} ({k}, {lo:.1f}-{min(hi, d['time_s'][-1] / 3600):.1f} h)"
                      for n, k, lo, hi in blocks))
    with tempfile.TemporaryDirectory() as tmp:
        cells = run(RECORD, d, blocks, channels, Path(tmp))
    print_table(cells, [b[0] for b in blocks], channels)
    if args.save:  # each cell's figures and fit's verdict, to judge other settings later
        Path(args.save).write_text(json.dumps([
            {"block": c.block, "channel": c.channel, "compd": c.compd, "base": c.base,
             "none_mae": c.none_mae, "before": c.before, "fit_tb": c.fit_tb,
             "fit_avg": c.fit_avg,
             "written": c.choice.verdict, "what": c.choice.what, "judge": c.choice.judge}
            for c in cells], indent=1))


def shop(seeds: list[int]) -> None:
    """The same protocol on the simulated shop machine: 48 h per seed, day 2
    held out (masked from every loss), both models run from the record's
    cold start and scored on day 2."""
    from compd.cli import main as cli

    cells: list[Cell] = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in seeds:
            record = Path(tmp) / f"shop{seed}.csv"
            with contextlib.redirect_stdout(io.StringIO()):
                cli(["sim", "--record", str(record), "--machine", "shop", "--hours", "48",
                     "--period-s", "60", "--seed", str(seed)])
            d = read(record)
            for c in run(record, d, [(f"seed {seed} day 2", "end", 24.0, END)], ["dz_um"],
                         Path(tmp)):
                cells.append(Cell(c.block, f"seed {seed}", c.compd, c.base, c.none_mae,
                                  c.choice, c.pair))
    print("\nshop machine, day 2 held out: MAE µm compd / textbook (ratio)")
    print("| seed | compd MAE | compd RMS | textbook MAE | textbook RMS | ratio | stability |")
    print("|---|---|---|---|---|---|---|")
    for c in cells:
        print(f"| {c.channel} | {c.compd[0]:.2f} | {c.compd[1]:.2f} | {c.base[0]:.2f} | "
              f"{c.base[1]:.2f} | {c.ratio:.2f} | {c.choice.stability:.2f} |")
    r = [c.ratio for c in cells]
    print(f"geometric mean {geo(r):.3f}, worst {worst(r):.2f}")


if __name__ == "__main__":
    main()
