"""Hostile input for `compd plan` and LinuxCNC's interpreter to run its programs:
what tests/compd/offline/plan/test_plan_hostile.py feeds the command and checks.

- `hostile_names(rng, n)`: file names that carry a comment command of
  LinuxCNC (``LOGOPEN,victim.ini``, ``MSG,…``, ``PY,…``), G-code words, the
  comment signs of the three dialects, letters outside ASCII and past U+FFFF,
  padded so that any word may fall at the start of a wrapped line.
- `hostile_calls(rng, dialect, n)`: measuring-cycle calls, a valid one with
  words, signs and blocks spliced in (``M03 S30000``, ``M99``, ``G10 L2 P1
  Z-100.``, ``CYCLE978(0,1) G0 X-900 ()``, a second cycle…), or valid ones.
- `run_rs274(paths)`: ``rs274 -g`` on each program (a few at a time) and the
  canonical calls it printed; `canon_errors` what in them a plan program must
  not do.
"""

from __future__ import annotations

import os
import random
import re
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path

RS274 = shutil.which("rs274")

#: LinuxCNC's comment commands, in the cases and spacings its interpreter takes
COMMENT_COMMANDS = ("LOGOPEN,victim.ini", "logopen,victim.ini", "  LoGoPeN,victim.ini",
                    "LOGAPPEND,victim.ini", "LOGCLOSE", "LOG,written", "MSG,pwned",
                    "msg,pwned", "DEBUG,#5220", "PRINT,#<_x>", "PROBEOPEN victim.txt",
                    "PROBECLOSE", "ABORT,stopped", "PY,import os", "PYRUN,x", "PYRELOAD",
                    "TASK,x")
_WORDS = ("G91 G00 Z-100.", "M03 S30000", "M99", "M30", "G10 L2 P1 Z-100.", "O2000", "%",
          "G96 S1000", "#1=5", "/", "N10", "MCALL CYCLE800", "$P_UIFR[1]=0")
_SIGNS = "();%#$\"'\\&*?[]{}<>|!`~^=,:."
_LETTERS = ("ä", "Halle 3", "µm", "😀", "𝔊", "中文", "ß", "é")


def hostile_names(rng: random.Random, n: int) -> list[str]:
    """`n` printable file names (no "/", at most 100 bytes in UTF-8: the
    temporary file written first holds the name and its suffix again)."""
    names: list[str] = []
    while len(names) < n:
        parts = [rng.choice("abcXYZ") * rng.randrange(0, 70)]
        for _ in range(rng.randrange(1, 4)):
            kind = rng.randrange(4)
            if kind == 0:
                piece = rng.choice(COMMENT_COMMANDS)
                piece = rng.choice((piece, f"({piece})", f"){piece}(", f"; {piece}"))
            elif kind == 1:
                piece = rng.choice(_WORDS)
            elif kind == 2:
                piece = "".join(rng.choice(_SIGNS) for _ in range(rng.randrange(1, 6)))
            else:
                piece = rng.choice(_LETTERS)
            parts += [piece, " " * rng.randrange(0, 3), "x" * rng.randrange(0, 30)]
        name = "".join(parts) + rng.choice((".ngc", ".nc", ".mpf", ".NGC", ""))
        name = name.replace("/", "_").lstrip() or "x"
        if len(name.encode("utf-8")) <= 100 and name not in (".", ".."):
            names.append(name)
    return names


FANUC_VALID = ("G65 P9810 Z-10. F500.", "G65 P9811 Z-5. S1 Q2. H3", "G65 P1",
               "G65 P9999 A1. B-2.5 C.5 X0. Y-0.001 M12 T4")
SINUMERIK_VALID = ("CYCLE978(0,1,,1,-10,100,,3,1)", "CYCLE977(1,2)", "CYCLE982()", "L9810",
                   "CYCLE998(,,,-5.5,.5)")
_FANUC_HOSTILE = ("M03", "S30000", "M03 S30000", "G91 G00 Z-100.", "M99", "G10 L2 P1 Z-100.",
                  "O2000", "(MSG,X)", "(LOGOPEN,V.INI)", ";", "%", "G00", "X-900.", "M30",
                  "#1=5", "GOTO 1", "N10", "/", "G65 P9810", "P9810", "L2", "\n", "M98 P2000",
                  "G28 G91 Z0.", "G53 Z-100.", "Z-10", "Z1E3", "Z-10.5.", "Z123456789.",
                  "S1.5", "g65", "\uff2765", "P\u0663", "Z-1\u0660.", "G65 P9810 Z-1.",
                  "G66 P9810", "A", "P0", "P10000", "Q", "-", "Z--1.", "Z+-1.")
_SINUMERIK_HOSTILE = ("G0 X-900 Y-900 Z-900", "M3 S30000", "()", "; x", 'MSG("x")',
                      "CYCLE800(1)", "PUTFTOC(1,1,1)", "SETAL(61000)", "MCALL", "G91", ",G0",
                      ")", "(", '"x"', "R1=5", "$P_UIFR[1]", "GOTOF L", "N10", "1e3", "L0",
                      "L12345678", "\n", "CYCLE978(0,1)", "TRANS Z=5", "M30", "1.2.3", "--1",
                      "cycle978(0)", "CYCLE978 (0)", "CYCLE9780(1)", "\u0661", "0x10")


def hostile_calls(rng: random.Random, dialect: str, n: int) -> list[str]:
    """`n` probe calls for `dialect`: about one in five valid, the rest a valid
    call with one to three hostile pieces spliced in at word or character places."""
    valid = FANUC_VALID if dialect == "fanuc" else SINUMERIK_VALID
    hostile = _FANUC_HOSTILE if dialect == "fanuc" else _SINUMERIK_HOSTILE
    calls: list[str] = []
    while len(calls) < n:
        call = rng.choice(valid)
        if rng.random() >= 0.2:
            for _ in range(rng.randrange(1, 4)):
                at = rng.randrange(len(call) + 1)
                sep = rng.choice((" ", "", ","))
                call = call[:at] + sep + rng.choice(hostile) + sep + call[at:]
        calls.append(call)
    return calls


_CALL = re.compile(r"^\s*\d+ N\.+ ([A-Z_0-9]+)\((.*)\)\s*$")
#: the canonical calls a plan program makes (its comments, modal state, moves,
#: the spindle, probing, M68, dwells, the end) and rs274's own set-up
EXPECTED = frozenset({
    "USE_LENGTH_UNITS", "SET_G5X_OFFSET", "SET_G92_OFFSET", "SET_XY_ROTATION",
    "SET_FEED_REFERENCE", "ON_RESET", "COMMENT", "SET_SPINDLE_MODE", "SET_FEED_MODE",
    "SET_FEED_RATE", "SELECT_PLANE", "SET_SPINDLE_SPEED", "START_SPINDLE_CLOCKWISE",
    "STOP_SPINDLE_TURNING", "STRAIGHT_TRAVERSE", "TURN_PROBE_ON", "TURN_PROBE_OFF",
    "STRAIGHT_PROBE", "SET_AUX_OUTPUT_VALUE", "DWELL", "PROGRAM_END"})


@dataclass(frozen=True)
class Run:
    returncode: int
    stdout: str
    stderr: str


def rs274_env(home: Path) -> dict[str, str]:
    """rs274's environment with a HOME of its own: it maps the tool table at
    ``$HOME/.tool.mmap``, truncating the file first, so two at once with one HOME
    (or one beside a running LinuxCNC) crash each other with SIGBUS."""
    home.mkdir(parents=True, exist_ok=True)
    return {**os.environ, "HOME": str(home)}


def run_rs274(paths: list[Path], *, at_once: int = 4) -> list[Run]:
    """``rs274 -g`` on every program, `at_once` processes at a time, in order."""
    assert RS274 is not None
    runs: list[Run] = []
    for k in range(0, len(paths), at_once):
        procs = [subprocess.Popen([RS274, "-g", str(p)], cwd=p.parent, text=True,
                                  env=rs274_env(p.parent / f".rs274-home-{k + j}"),
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE)
                 for j, p in enumerate(paths[k:k + at_once])]
        for proc in procs:
            out, err = proc.communicate(timeout=120)
            runs.append(Run(proc.returncode, out, err))
    return runs


def calls_of(run: Run) -> list[tuple[str, str]]:
    return [(m.group(1), m.group(2)) for m in map(_CALL.match, run.stdout.splitlines()) if m]


def canon_errors(run: Run, program: str, speeds: set[float], axes: set[str]) -> list[str]:
    """What in rs274's reading of `program` a plan program must not do: an error,
    output that is not a canonical call (PRINT, Python), a call outside
    `EXPECTED` (MESSAGE, LOGOPEN…), a COMMENT the program does not hold as
    its own, a spindle in constant surface speed or at a speed not planned, a
    move of an axis not named."""
    errors: list[str] = []
    if run.returncode != 0 or run.stderr.strip() not in ("", "executing"):
        errors.append(f"rs274 failed ({run.returncode}): {run.stderr.strip()[:200]}")
    stray = [line for line in run.stdout.splitlines()
             if line.strip() and _CALL.match(line) is None]
    if stray:
        errors.append(f"output that is no canonical call: {stray[:3]}")
    own = {c.strip() for c in re.findall(r"\(([^()]*)\)", program)}
    index = {"X": 0, "Y": 1, "Z": 2}
    calls = calls_of(run)
    for name, args in calls:
        if name not in EXPECTED:
            errors.append(f"{name}({args}): a call no plan program makes")
        elif name == "COMMENT":
            text = args.strip().strip('"')
            if not text.startswith("interpreter:") and text.strip() not in own:
                errors.append(f"COMMENT({args}): not one of the program's comments")
        elif name == "SET_SPINDLE_MODE" and args.split()[-1] != "0.0000":
            errors.append(f"SET_SPINDLE_MODE({args}): constant surface speed")
        elif name == "SET_SPINDLE_SPEED" and float(args.split(",")[1]) not in speeds:
            errors.append(f"SET_SPINDLE_SPEED({args}): a speed not planned")
        elif name in ("STRAIGHT_TRAVERSE", "STRAIGHT_PROBE"):
            values = [float(v) for v in args.split(",")]
            moved = {a for a, i in index.items() if values[i] != 0.0} | set(
                "ABC"[i - 3] for i in (3, 4, 5) if values[i] != 0.0)
            if moved - axes:
                errors.append(f"{name}({args}): moves {sorted(moved - axes)}, not named")
    names = [name for name, _ in calls]
    if "PROGRAM_END" not in names or set(names[names.index("PROGRAM_END") + 1:]) - {"ON_RESET"}:
        errors.append("the program did not run to PROGRAM_END")
    return errors
