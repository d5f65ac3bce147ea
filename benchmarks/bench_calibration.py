"""Issue 11's calibration figures, through the command line as a user runs it.

1. The 48 h split: `compd sim --record all.csv --program spectrum --hours 48
   --period-s 60 --seed 5`, halves; `compd fit` on the first (bearing, motor,
   column, ambient, orders 3-3; the forced per-term-oe with --force, as the
   check warns about it); `compd replay` of the second half with each
   --init, against the model run continuously from the start of the whole
   record and scored on the second half.
2. The shop machine (`compd sim --record --machine shop --hours 48`), per
   seed: calibrate on day 1 with --candidates over the sixteen sensors and
   the spindle speed (--max-terms 3), verify on day 2 (it starts warm);
   beside it, in the same run, the shared-denominator ARX least squares on
   the best pair of the same search (`--structure arx`).

With ``--change`` only 2, on records whose day 2 is the day with a change
(`--change ambient+3K,heat+30% --change-at-h 24`: a warmer room and more
heat than day 1 saw), so that the inputs are chosen on one day and judged on
a day the model never saw.

Run: OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_calibration.py [--change]
[SEEDS…]
"""

from __future__ import annotations

import contextlib
import io
import json
import sys
import tempfile
import time
from pathlib import Path

from compd.cli import main as cli


def _run(argv: list[str]) -> dict[str, object]:
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = cli(argv)
    if code != 0:
        raise SystemExit(f"compd {' '.join(argv)} exited {code}")
    text = out.getvalue().strip().splitlines()
    return json.loads(text[-1]) if text and text[-1].startswith("{") else {}


def _halves(full: Path, first: Path, second: Path) -> None:
    lines = full.read_text().splitlines()
    head, rows = lines[0], lines[1:]
    half = len(rows) // 2
    first.write_text("\n".join([head, *rows[:half + 1]]) + "\n")
    second.write_text("\n".join([head, *rows[half:]]) + "\n")


def split_48h(d: Path) -> None:
    full, h1, h2 = d / "all.csv", d / "h1.csv", d / "h2.csv"
    _run(["sim", "--record", str(full), "--program", "spectrum", "--hours", "48",
          "--period-s", "60", "--seed", "5"])
    _halves(full, h1, h2)
    for structure in ("auto", "per-term-oe"):
        model = d / f"h1-{structure}.toml"
        # the papers' structure is forced on purpose, to measure it beside compd's
        # choice: --force writes it although `compd check` warns about it (fit
        # prints the warning)
        force = ["--force"] if structure != "auto" else []
        _run(["fit", str(h1), "--column", "dz_um", "--term", "bearing", "--term", "motor",
              "--term", "column", "--term", "ambient", "--orders", "3-3", "--structure",
              structure, "-o", str(model), "--json", *force])
        cont = _run(["replay", str(model), str(full), "--column", "dz_um", "--init", "rest",
                     "--score-from", "86400", "--json"])
        figs = {i: _run(["replay", str(model), str(h2), "--column", "dz_um", "--init", i,
                         "--json"]) for i in ("estimate", "steady", "rest")}
        print(f"48 h split, fit --structure {structure}: second half replayed "
              + ", ".join(f"{i} {f['fit_percent']:.2f} %" for i, f in figs.items())
              + f"; continuous {cont['fit_percent']:.2f} % / {cont['range_reduction']:.2f}x")


CHANGE = ["--change", "ambient+3K,heat+30%", "--change-at-h", "24"]


def shop(d: Path, seed: int, change: bool = False) -> None:
    full, day1, day2 = d / f"shop{seed}.csv", d / f"d1-{seed}.csv", d / f"d2-{seed}.csv"
    _run(["sim", "--record", str(full), "--machine", "shop", "--hours", "48", "--period-s",
          "60", "--seed", str(seed), *(CHANGE if change else [])])
    _halves(full, day1, day2)
    model = d / f"shop{seed}.toml"
    t0 = time.perf_counter()
    fit = _run(["fit", str(day1), "--column", "dz_um", "--candidates", "t*_degC",
                "--candidates", "spindle_rpm", "--max-terms", "3", "-o", str(model), "--json"])
    took = time.perf_counter() - t0
    ours = _run(["replay", str(model), str(day2), "--column", "dz_um", "--json"])
    subsets = fit["subsets"]
    assert isinstance(subsets, list)
    pair = max((s for s in subsets if len(s["inputs"]) == 2),
               key=lambda s: s["validation_fit_percent"])["inputs"]
    base_model = d / f"arx{seed}.toml"
    terms = [a for ch in pair for a in ("--term", ch)]
    _run(["fit", str(day1), "--column", "dz_um", *terms, "--structure", "arx", "-o",
          str(base_model), "--json"])
    base = _run(["replay", str(base_model), str(day2), "--column", "dz_um", "--json"])
    terms_info = fit["terms"]
    assert isinstance(terms_info, list)
    chosen = " + ".join(t["name"] for t in terms_info)
    ok = ours["fit_percent"] >= 88.0 and ours["range_reduction"] >= 7.0 \
        and ours["fit_percent"] > base["fit_percent"]  # type: ignore[operator]
    day = " (day 2 changed)" if change else ""
    print(f"shop seed {seed}{day}: {chosen} ({terms_info[0]['selection']['structure']}, "
          f"{len(subsets)} subsets, fit {took:.1f} s): day 2 {ours['fit_percent']:.2f} % / "
          f"{ours['range_reduction']:.2f}x; ARX on {' + '.join(pair)}: "
          f"{base['fit_percent']:.2f} % / {base['range_reduction']:.2f}x "
          f"[{'met' if ok else 'MISSED'}: >= 88 %, >= 7x, above ARX]")


def main() -> None:
    change = "--change" in sys.argv[1:]
    seeds = [int(a) for a in sys.argv[1:] if a != "--change"] or [1, 2, 3, 4, 5]
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        if not change:
            split_48h(d)
        for seed in seeds:
            shop(d, seed, change)


if __name__ == "__main__":
    main()
