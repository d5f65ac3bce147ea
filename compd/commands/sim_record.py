"""``compd sim --record``: an offline calibration record, written faster than real time
without any server: the demo plant under a program, the shop machine
(`drivers.sim.shop`) or the ball-screw axis (`drivers.sim.ballscrew`)."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from compd.sysexits import EX_DATAERR

#: an offline record longer than this many rows is refused (~0.6 GB of CSV)
MAX_RECORD_ROWS = 10_000_000


def _too_many_rows(duration_s: float, period_s: float) -> bool:
    """Whether a record of `duration_s` every `period_s` would pass MAX_RECORD_ROWS
    (then said on stderr, in hours and rows)."""
    if duration_s / period_s <= MAX_RECORD_ROWS:
        return False
    print(f"compd sim: {duration_s / 3600:g} h every {period_s:g} s is "
          f"{duration_s / period_s:.3g} rows; at most {MAX_RECORD_ROWS:,}", file=sys.stderr)
    return True


def record(args: argparse.Namespace) -> int:
    """``compd sim --record``: the chosen machine's record written (exit 0), or one line
    on stderr and EX_DATAERR when it would hold more than MAX_RECORD_ROWS rows."""
    from compd.outfiles import check_output, write_atomically
    from drivers.sim.offline import record_program
    from drivers.sim.programs import make_program

    check_output(args.record, "record", force=args.force)
    if args.machine == "shop":
        return _record_shop(args)
    if args.machine == "ballscrew":
        return _record_ballscrew(args)
    program = make_program(args.program, seed=args.seed, hours=args.hours)
    if _too_many_rows(program.duration_s, args.period_s):
        return EX_DATAERR
    rows = 0

    def write(tmp: Path) -> None:
        nonlocal rows
        rows = record_program(tmp, program, seed=args.seed, period_s=args.period_s,
                              probe_noise_um=args.probe_noise_um)

    write_atomically(args.record, write, "record", force=args.force)
    print(f"compd sim: wrote {rows} rows ({program.name}, {program.duration_s / 3600:g} h, "
          f"period {args.period_s:g} s, seed {args.seed}) to {args.record}")
    return 0


def _record_shop(args: argparse.Namespace) -> int:
    from compd.outfiles import write_atomically
    from drivers.sim.shop import simulate_shop, write_shop_record

    hours = args.hours if args.hours is not None else 24.0
    if _too_many_rows(hours * 3600.0, args.period_s):
        return EX_DATAERR
    change = None
    if args.change is not None:
        change = dataclasses.replace(args.change, at_h=args.change_at_h)
    columns = simulate_shop(hours, period_s=args.period_s, seed=args.seed, change=change)
    rows = len(columns["time_s"])
    write_atomically(args.record, lambda tmp: write_shop_record(str(tmp), columns), "record",
                     force=args.force)
    what = "" if change is None else (f", change ambient {change.ambient_k:+g} K and heat "
                                      f"x{change.heat_factor:g} from {change.at_h:g} h")
    print(f"compd sim: wrote {rows} rows (shop machine, workday program, {hours:g} h, period "
          f"{args.period_s:g} s, seed {args.seed}{what}) to {args.record}")
    return 0


def _record_ballscrew(args: argparse.Namespace) -> int:
    from compd.outfiles import write_atomically
    from drivers.sim.ballscrew import (
        DEFAULT_POSITIONS_MM,
        simulate_ballscrew,
        write_ballscrew_record,
    )

    hours = args.hours if args.hours is not None else 24.0
    positions = args.positions if args.positions is not None else DEFAULT_POSITIONS_MM
    if _too_many_rows(hours * 3600.0, args.period_s):
        return EX_DATAERR
    columns = simulate_ballscrew(hours, period_s=args.period_s, seed=args.seed,
                                 positions_mm=positions, probe_noise_um=args.probe_noise_um)
    rows = len(columns["time_s"])
    write_atomically(args.record,
                     lambda tmp: write_ballscrew_record(str(tmp), columns, positions),
                     "record", force=args.force)
    print(f"compd sim: wrote {rows} rows (ball-screw machine, axis workday, {hours:g} h, "
          f"period {args.period_s:g} s, seed {args.seed}, displacement at "
          f"{','.join(f'{x:g}' for x in positions)} mm) to {args.record}")
    return 0
