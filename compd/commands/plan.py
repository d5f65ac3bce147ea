"""`compd plan --hours H --speeds S1,S2,… --dialect D -o FILE`: the calibration
experiment as a G-code program (`compd.offline.plan`), and beside it the
recorder-only daemon config that records its run for `compd fit` (FILE's stem +
``.recorder.toml``): with ``--config CONFIG`` complete (the machine's
[machine], [controller] and [channels] copied, the config checked first: a bad
one is exit 78 naming the key), else with those tables left for the user.

Both files are checked before anything is written (`compd.outfiles`: never
over an existing file without ``--force``, never a directory or a symbolic
link) and written atomically. A bad argument is one line on stderr and exit 64;
warnings about the design (steps too short to heat through, a measuring cycle
sparser than the steps) go to stderr once the files are written.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from compd.argtypes import Wholes, count, distinct_wholes, number
from compd.commands import plan_traverse
from compd.sysexits import EX_USAGE

if TYPE_CHECKING:
    from compd.offline.plan.calls import ProbeCall
    from compd.offline.plan.program import Program
    from compd.offline.plan.schedule import Experiment

HELP = "write the calibration experiment (spindle steps, rests, measuring cycles) as G-code"

HOURS = number(0.0, 168.0, lo_open=True)
REST_H = number(0.0, 168.0, lo_open=True)
#: the measuring cycle: every minute to once a week, as `compd sim --probe-every-min`
PROBE_EVERY_MIN = number(1.0, 7 * 24 * 60.0)
DEPTH_MM = number(0.0, 500.0, lo_open=True)
FEED_MM_MIN = number(0.0, 10_000.0, lo_open=True)
SPINDLE_STOP_S = number(0.0, 600.0)
#: a simulator's speed-up: every dwell divided by it (1: a real machine)
TIME_SCALE = number(1.0, 10_000.0)
#: whole rpm (FANUC's S takes no decimal point), at most this many speeds
MAX_RPM = 100_000
MAX_SPEEDS = 12
#: positions in mm, within a machine tool's travel and FANUC's 8 digits (IS-B)
MAX_POSITION_MM = 10_000.0


_SPEEDS = Wholes(one="a spindle speed", whole="whole number of rpm", unit="rpm",
                 each="speed", many="speeds", listing="spindle speeds in rpm",
                 example="1250,2500,5000")


def speeds(text: str) -> list[int]:
    """An argparse type: comma-separated whole rpm, distinct, each 1 … MAX_RPM."""
    return distinct_wholes(text, MAX_RPM, MAX_SPEEDS, _SPEEDS)


def position(text: str) -> dict[str, float]:
    """An argparse type: AXIS=MM pairs for X, Y and Z, comma-separated (Z=100,X=0)."""
    result: dict[str, float] = {}
    for part in text.split(","):
        axis, sep, value = part.strip().partition("=")
        axis = axis.strip().upper()
        if not sep or axis not in ("X", "Y", "Z"):
            raise argparse.ArgumentTypeError(f"a position is AXIS=MM for X, Y, Z, "
                                             f"comma-separated (e.g. X=0,Y=0,Z=100); "
                                             f"got {part.strip()!r}")
        if axis in result:
            raise argparse.ArgumentTypeError(f"{axis} is given twice in {text!r}")
        try:
            mm = float(value)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{axis}: not a number: {value!r}") from None
        if not math.isfinite(mm) or abs(mm) > MAX_POSITION_MM:
            raise argparse.ArgumentTypeError(f"{axis}: a finite position within "
                                             f"±{MAX_POSITION_MM:g} mm: {value!r}")
        result[axis] = mm
    return result


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from compd.offline.plan.dialects import DIALECTS

    parser.add_argument("--hours", type=HOURS, required=True,
                        help="the schedule's length in hours (0 < H <= 168): steps and "
                             "rests; the measuring cycles add their own time")
    parser.add_argument("--speeds", type=speeds, default=None, metavar="RPM,RPM,…",
                        help="spindle speeds in whole rpm, each once: held rising, rest, "
                             "then held falling, rest (required unless --traverse)")
    parser.add_argument("--rest-h", type=REST_H, default=None, metavar="R",
                        help="each of the two rests in hours (default: as long as a step)")
    parser.add_argument("--probe-every-min", type=PROBE_EVERY_MIN, default=None,
                        metavar="MINUTES",
                        help="a measuring cycle every MINUTES minutes of the schedule, and "
                             "at its start and end (default: none; needs --safe-position)")
    parser.add_argument("--dialect", choices=DIALECTS, required=True,
                        help="the controller: linuxcnc (G38.2 probing), fanuc or sinumerik "
                             "(your measuring cycle, --probe-call)")
    parser.add_argument("-o", "--output", required=True, metavar="FILE",
                        help="the program file; the recorder settings go beside it as "
                             "STEM.recorder.toml")
    parser.add_argument("--config", default=None, metavar="CONFIG",
                        help="the machine's daemon config: its [machine], [controller] and "
                             "[channels] go into the recorder config, which then runs as it "
                             "is (default: left for you to add)")
    parser.add_argument("--force", action="store_true",
                        help="replace existing output files")
    parser.add_argument("--safe-position", type=position, default=None, metavar="AXIS=MM,…",
                        help="where the program goes first and between measuring cycles, "
                             "work coordinates G54 (e.g. Z=100 or X=0,Y=0,Z=100; Z first); "
                             "only the axes named here and in --probe-at move")
    parser.add_argument("--probe-at", type=position, default=None, metavar="AXIS=MM,…",
                        help="where the measuring cycle starts, e.g. above a tool setter "
                             "(linuxcnc: G38.2 probes down in Z from here; needs Z)")
    parser.add_argument("--probe-depth-mm", type=DEPTH_MM, default=10.0,
                        help="linuxcnc: how far below --probe-at's Z the probe may go "
                             "(default 10)")
    parser.add_argument("--probe-feed", type=FEED_MM_MIN, default=100.0, metavar="MM_MIN",
                        help="linuxcnc: the probing feed in mm/min (default 100)")
    parser.add_argument("--probe-call", default=None, metavar="BLOCK",
                        help="the measuring cycle, one call with numeric arguments and "
                             "nothing else: fanuc 'G65 P9810 Z-10. F500.' (a macro "
                             "P1-P9999); sinumerik a Siemens measuring cycle "
                             "'CYCLE978(0,1,,1,-10,100,,3,1)' or a subprogram 'L9810'")
    parser.add_argument("--spindle-stop-s", type=SPINDLE_STOP_S, default=5.0,
                        help="seconds the spindle runs down after M5 before a measuring "
                             "cycle moves (default 5)")
    parser.add_argument("--time-scale", type=TIME_SCALE, default=1.0, metavar="N",
                        help="divide every dwell by N (1 … 10000), for a simulated machine "
                             "whose plant and daemon run at [machine] time_scale = N; the "
                             "header says so. Never on a real machine (default 1)")
    parser.add_argument("--program-number", type=count(1, 9999), default=1000,
                        help="fanuc: the O number (default 1000)")
    plan_traverse.add_arguments(parser, max_position_mm=MAX_POSITION_MM)


def _position_text(position: dict[str, float]) -> str:
    return ",".join(f"{axis}={mm:g}" for axis, mm in position.items())


def _summary(args: argparse.Namespace, call: ProbeCall | None) -> str:
    """The options that shaped the program, as the command line would say them
    (the probe call as written in the program, from its parsed value)."""
    parts = [f"--hours {args.hours:g}", f"--speeds {','.join(map(str, args.speeds))}"]
    if args.rest_h is not None:
        parts.append(f"--rest-h {args.rest_h:g}")
    parts.append(f"--dialect {args.dialect}")
    if args.time_scale != 1.0:
        parts.append(f"--time-scale {args.time_scale:g}")
    if args.safe_position is not None:
        parts.append(f"--safe-position {_position_text(args.safe_position)}")
    if args.probe_every_min is not None:
        parts += [f"--probe-every-min {args.probe_every_min:g}",
                  f"--spindle-stop-s {args.spindle_stop_s:g}"]
        if args.probe_at is not None:
            parts.append(f"--probe-at {_position_text(args.probe_at)}")
        if args.dialect == "linuxcnc":
            parts += [f"--probe-depth-mm {args.probe_depth_mm:g}",
                      f"--probe-feed {args.probe_feed:g}"]
        elif call is not None:
            parts.append(f"--probe-call '{call.block}'")
    return f"Written by: compd plan {' '.join(parts)}."


def _machine_tables(path: Path) -> dict[str, Any]:
    """[machine], [controller] and [channels] of a daemon config that loads (a
    ConfigError naming the key otherwise: exit 78)."""
    from compd.config.loader import load_config
    from compd.errors import ConfigError
    from compd.infiles import MAX_CONFIG_BYTES, InputError, read_toml_document

    load_config(path)  # the whole config checked, as compd check would
    try:
        _, doc = read_toml_document(path, "config file", MAX_CONFIG_BYTES)
    except InputError as exc:  # changed since: as any unreadable config
        raise ConfigError("", str(exc)) from None
    return {k: doc[k] for k in ("machine", "controller", "channels") if k in doc}


def _usage(message: str) -> int:
    print(f"compd plan: {message}", file=sys.stderr)
    return EX_USAGE


def run(args: argparse.Namespace) -> int:
    from compd.offline.plan.recorder import recorder_config
    from compd.offline.plan.schedule import PlanError
    from compd.outfiles import check_output, write_atomically

    out = Path(args.output)
    if any(not c.isprintable() for c in args.output):
        return _usage(f"{args.output!r}: a program's name is printable characters")
    side = out.with_name(f"{out.stem}.recorder.toml") if out.name else out
    if args.probe_every_min is None and (args.probe_at or args.probe_call):
        return _usage("--probe-at and --probe-call say how to measure: they go with "
                      "--probe-every-min")
    trouble = plan_traverse.problem(args)
    if trouble is None and args.traverse is None and args.speeds is None:
        trouble = "--speeds is required (or --traverse AXIS for the traverse experiment)"
    if trouble is not None:
        return _usage(trouble)
    try:
        if args.traverse is not None:
            program, exp, warnings = plan_traverse.build(args)
        else:
            program, exp = _spindle_program(args)
            warnings = exp.warnings
    except PlanError as exc:
        return _usage(str(exc))
    check_output(args.output, "program", force=args.force)  # the text: "dir/" is refused
    if side == out:
        return _usage(f"{out}: the program and its recorder settings would share a name")
    check_output(side, "recorder settings", force=args.force)
    machine = None if args.config is None else _machine_tables(Path(args.config))
    fragment = recorder_config(out, exp, args.dialect, args.time_scale, machine=machine,
                               source=args.config, positions_mm=args.positions or ())
    write_atomically(out, lambda tmp: tmp.write_text(program.text, encoding="ascii"),
                     "program", force=args.force)
    write_atomically(side, lambda tmp: tmp.write_text(fragment, encoding="utf-8"),
                     "recorder settings", force=args.force)
    axes = ", ".join(program.axes) or "none"
    scaled = "" if args.time_scale == 1.0 else f" at time scale {args.time_scale:g}"
    what = "measuring passes" if args.traverse is not None else "measuring cycles"
    print(f"compd plan: wrote {out} ({args.dialect}, {exp.duration_ms / 3_600_000:g} h of "
          f"schedule, {program.dwell_total_ms / 1000:.3f} s of dwell in all{scaled}, "
          f"{exp.measurements} {what}, axes moved: {axes}) and {side}")
    for warning in warnings:  # after the files: a failure stays one line
        print(f"compd plan: warning: {warning}", file=sys.stderr)
    return 0


def _spindle_program(args: argparse.Namespace) -> tuple[Program, Experiment]:
    """The spindle experiment's program and schedule; PlanError (one line)."""
    from compd.offline.plan.dialects import Probing, dialect
    from compd.offline.plan.program import make_program
    from compd.offline.plan.schedule import PlanError, design

    words = dialect(args.dialect, program_number=args.program_number)
    call = None if args.probe_call is None else words.parse_call(args.probe_call)
    if args.probe_every_min is not None and call is None and args.dialect != "linuxcnc":
        raise PlanError(f"{args.dialect}: the measuring cycle is yours: give --probe-call")
    exp = design(args.hours, args.speeds, rest_h=args.rest_h,
                 probe_every_min=args.probe_every_min)
    probing = None
    if args.safe_position is not None or args.probe_at is not None:
        probing = Probing(safe=args.safe_position or {}, at=args.probe_at or {},
                          depth_mm=args.probe_depth_mm, feed_mm_min=args.probe_feed,
                          call=call, spindle_stop_s=args.spindle_stop_s)
    program = make_program(exp, words, probing, summary=_summary(args, call),
                           recorder=True, time_scale=args.time_scale)
    return program, exp
