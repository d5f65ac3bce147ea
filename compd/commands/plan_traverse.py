"""`compd plan --traverse AXIS --positions MM,MM,… --duties PCT,PCT,…`: the traverse
experiment of a position-dependent calibration (`compd.offline.plan.traverse`),
with the plan command's conventions: the same --hours, --rest-h,
--probe-every-min (here: a measuring pass), --dialect, -o, --config,
--safe-position, --probe-call and --force, the recorder settings beside the
program, one line on stderr and exit 64 for a bad argument.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import TYPE_CHECKING

from compd.argtypes import Wholes, distinct_wholes, number

if TYPE_CHECKING:
    from compd.offline.plan.calls import ProbeCall
    from compd.offline.plan.program import Program
    from compd.offline.plan.schedule import Experiment

#: duty levels in whole percent of the time the axis moves, at most this many
MAX_DUTIES = 12
#: the traverse feed, mm/min (a machine tool's rapid rates reach 60 m/min)
FEED_MM_MIN = number(0.0, 60_000.0, lo_open=True)
#: the standstill at each measuring position, s
STOP_S = number(0.0, 600.0)


_DUTIES = Wholes(one="a duty", whole="whole percent", unit="%", each="duty",
                 many="duties", listing="axis duties in percent", example="25,50,90")


def duties(text: str) -> list[int]:
    """An argparse type: comma-separated whole percent, distinct, each 1 … 100."""
    return distinct_wholes(text, 100, MAX_DUTIES, _DUTIES)


def positions(max_mm: float) -> Callable[[str], tuple[float, ...]]:
    """An argparse type: two or more positions (mm) as `compd sim --positions` takes
    them, each within `max_mm` (the reach of a program's coordinates)."""
    from compd.commands.sim import _positions

    def parse(text: str) -> tuple[float, ...]:
        values = _positions(text)
        if any(abs(x) > max_mm for x in values):
            raise argparse.ArgumentTypeError(f"positions within ±{max_mm:g} mm, got {text!r}")
        return values

    return parse


def add_arguments(parser: argparse.ArgumentParser, *, max_position_mm: float) -> None:
    parser.add_argument("--traverse", type=str.upper, choices=("X", "Y", "Z"), default=None,
                        metavar="AXIS",
                        help="instead of spindle steps: the traverse experiment of a "
                             "position-dependent calibration, AXIS (X, Y or Z) moving as the "
                             "heat source, measured at --positions (needs --duties, "
                             "--probe-every-min, --safe-position)")
    parser.add_argument("--positions", type=positions(max_position_mm), default=None,
                        metavar="MM,MM,…",
                        help="with --traverse: where each measuring pass stops along AXIS "
                             "(two or more, mm); the traverse runs between the lowest and "
                             "the highest")
    parser.add_argument("--duties", type=duties, default=None, metavar="PCT,PCT,…",
                        help="with --traverse: the share of the time the axis moves, whole "
                             "percent, each once: held rising, rest, held falling, rest")
    parser.add_argument("--feed", type=FEED_MM_MIN, default=5000.0, metavar="MM_MIN",
                        help="with --traverse: the traverse feed in mm/min (default 5000)")
    parser.add_argument("--stop-s", type=STOP_S, default=10.0, metavar="S",
                        help="with --traverse: the standstill at each measuring position, "
                             "seconds (default 10)")


def _summary(args: argparse.Namespace, call: ProbeCall | None) -> str:
    from compd.offline.plan.dialects import num

    parts = [f"--traverse {args.traverse}",
             f"--positions {','.join(num(x) for x in args.positions)}",
             f"--duties {','.join(map(str, args.duties))}", f"--hours {args.hours:g}"]
    if args.rest_h is not None:
        parts.append(f"--rest-h {args.rest_h:g}")
    parts += [f"--feed {args.feed:g}", f"--stop-s {args.stop_s:g}",
              f"--probe-every-min {args.probe_every_min:g}", f"--dialect {args.dialect}"]
    if args.safe_position is not None:
        safe = ",".join(f"{axis}={mm:g}" for axis, mm in args.safe_position.items())
        parts.append(f"--safe-position {safe}")
    if call is not None:
        parts.append(f"--probe-call '{call.block}'")
    return f"Written by: compd plan {' '.join(parts)}."


def problem(args: argparse.Namespace) -> str | None:
    """What is wrong with the traverse's arguments, in one line (None: nothing)."""
    if args.traverse is None:
        given = [o for o, v in (("--positions", args.positions), ("--duties", args.duties))
                 if v is not None]
        return f"{given[0]} goes with --traverse AXIS" if given else None
    if args.speeds is not None:
        return ("--speeds goes without --traverse: the traverse experiment heats with the "
                "axis, the spindle stays stopped")
    for option, value in (("--positions", args.positions), ("--duties", args.duties),
                          ("--probe-every-min", args.probe_every_min),
                          ("--safe-position", args.safe_position)):
        if value is None:
            return f"--traverse needs {option}"
    if args.probe_at is not None:
        return ("--probe-at goes without --traverse: the passes stop at --positions along "
                f"{args.traverse}")
    if args.time_scale != 1.0:
        return ("--time-scale goes without --traverse: the traverse's moves take the "
                "machine's own time")
    if args.dialect == "linuxcnc" and args.probe_call is not None:
        return ("linuxcnc: --probe-call is for the fanuc and sinumerik dialects; the pass "
                "stands still at each position for your laser or ballbar")
    return None


def build(args: argparse.Namespace) -> tuple[Program, Experiment, tuple[str, ...]]:
    """The traverse program, its schedule and the warnings about it; PlanError
    (one line) when the experiment cannot be built."""
    from compd.offline.plan.dialects import dialect
    from compd.offline.plan.traverse import Traverse, make_traverse_program, traverse_design

    words = dialect(args.dialect, program_number=args.program_number)
    call = None if args.probe_call is None else words.parse_call(args.probe_call)
    exp, warnings = traverse_design(args.hours, args.duties, rest_h=args.rest_h,
                                    probe_every_min=args.probe_every_min)
    t = Traverse(args.traverse, tuple(args.positions), args.feed, args.stop_s,
                 dict(args.safe_position))
    program = make_traverse_program(exp, words, t, summary=_summary(args, call),
                                    call_block=None if call is None else call.block)
    return program, exp, warnings
