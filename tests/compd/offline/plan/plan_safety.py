"""What a `compd plan` program may do, checked block by block, apart from the
generator (a rule it gets wrong must not be wrong here the same way), for the
three dialects; LinuxCNC's programs are also run by LinuxCNC's own
interpreter (tests/compd/offline/plan/test_plan_hostile.py).

A program passes when:

- every block is one compd plan writes: the modal blocks, a rapid move of
  named axes, ``S… M3``, ``M5``, a dwell, the measuring cycle (LinuxCNC's
  ``G38.2`` and ``M68``; FANUC's and SINUMERIK's one call of a macro or
  measuring cycle with numbers for arguments), the end; a word outside that
  vocabulary (``M99``, ``G10``, ``G91``, ``O2000``, ``MCALL``…) is an error;
- no comment starts with a word a control runs as a command (LinuxCNC's
  ``MSG``, ``DEBUG``, ``PRINT``, ``LOGOPEN``, ``LOGAPPEND``, ``LOGCLOSE``,
  ``LOG``, ``PROBEOPEN``, ``PROBECLOSE``, ``ABORT``, ``PY…``; SINUMERIK's
  editor markers ``*RO*``, ``*HD*``, ``#SM``), and a comment holds no
  parenthesis, ``;`` or ``%`` (FANUC's and LinuxCNC's comment, SINUMERIK's);
- every modal group the moves and the spindle rely on (units, distance,
  plane, cutter compensation, canned cycle, work offset, feed, spindle speed
  mode; FANUC also scaling, rotation, polar coordinates and modal macro
  calls) is set to its value before the first move or spindle start and
  again after every call of the user's cycle, whose state is unknown.

`check` returns the errors ("line N: why") and what the program does: the
axes its moves name and the spindle speeds it starts.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

_NUM = r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)"
COMMAND_WORDS = ("MSG", "DEBUG", "PRINT", "LOGOPEN", "LOGAPPEND", "LOGAPPND", "LOGCLOSE",
                 "LOG", "PROBEOPEN", "PROBECLOSE", "ABORT", "PY", "TASK")
SINUMERIK_MARKERS = ("*RO*", "*HD*", "#SM", "#END")


@dataclass
class Effects:
    errors: list[str] = field(default_factory=list)
    axes: set[str] = field(default_factory=set)
    speeds: list[int] = field(default_factory=list)
    calls: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class Rules:
    """A dialect's vocabulary: G code → modal group, the value each group must
    hold, the shapes of its blocks."""

    groups: dict[str, str]
    required: dict[str, str]
    rapid: str
    spindle: re.Pattern[str]
    stop: str
    dwell: re.Pattern[str]
    end: frozenset[str]


def _g(codes: str, group: str) -> dict[str, str]:
    return {c: group for c in codes.split()}


_FANUC = Rules(
    groups={**_g("G20 G21", "units"), **_g("G90 G91", "distance"),
            **_g("G17 G18 G19", "plane"), **_g("G40 G41 G42", "radius comp"),
            **_g("G80 G81 G82 G83 G84 G85 G86 G87 G88 G89", "canned cycle"),
            **_g("G54 G55 G56 G57 G58 G59", "work offset"), **_g("G94 G95", "feed"),
            **_g("G96 G97", "spindle mode"), **_g("G50 G51", "scaling"),
            **_g("G68 G69", "rotation"), **_g("G15 G16", "polar"),
            **_g("G66 G67", "modal macro call")},
    required={"units": "G21", "distance": "G90", "plane": "G17", "radius comp": "G40",
              "canned cycle": "G80", "work offset": "G54", "feed": "G94",
              "spindle mode": "G97", "scaling": "G50", "rotation": "G69", "polar": "G15",
              "modal macro call": "G67"},
    rapid="G00", spindle=re.compile(r"S([0-9]+) M03"), stop="M05",
    dwell=re.compile(rf"G04 X{_NUM}"), end=frozenset({"M30"}))

_SINUMERIK = Rules(
    groups={**_g("G70 G71 G700 G710", "units"), **_g("G90 G91", "distance"),
            **_g("G17 G18 G19", "plane"), **_g("G40 G41 G42", "radius comp"),
            **_g("G500 G54 G55 G56 G57 G505 G506 G507", "work offset"),
            **_g("G93 G94 G95 G96 G961 G97 G971", "feed and spindle mode")},
    required={"units": "G71", "distance": "G90", "plane": "G17", "radius comp": "G40",
              "work offset": "G54", "feed and spindle mode": "G94"},
    rapid="G0", spindle=re.compile(r"S([0-9]+) M3"), stop="M5",
    dwell=re.compile(rf"G4 F{_NUM}"), end=frozenset({"M30"}))

_LINUXCNC = Rules(
    groups={**_g("G20 G21", "units"), **_g("G90 G91", "distance"),
            **_g("G17 G18 G19 G17.1 G18.1 G19.1", "plane"),
            **_g("G40 G41 G42 G41.1 G42.1", "radius comp"),
            **_g("G80 G81 G82 G83 G84 G85 G86 G87 G88 G89 G73 G76", "canned cycle"),
            **_g("G54 G55 G56 G57 G58 G59 G59.1 G59.2 G59.3", "work offset"),
            **_g("G93 G94 G95", "feed"), **_g("G96 G97", "spindle mode"),
            **_g("G7 G8", "lathe diameter")},
    required={"units": "G21", "distance": "G90", "plane": "G17", "radius comp": "G40",
              "canned cycle": "G80", "work offset": "G54", "feed": "G94",
              "spindle mode": "G97", "lathe diameter": "G8"},
    rapid="G0", spindle=re.compile(r"S([0-9]+) M3"), stop="M5",
    dwell=re.compile(rf"G4 P{_NUM}"), end=frozenset({"M2"}))

#: the user's call as each dialect may hold it: a macro or measuring cycle with numbers
_FANUC_CALL = re.compile(rf"G65 P([1-9][0-9]{{0,3}})((?: [A-FHIJKMQ-Z]{_NUM})*)")
_SINUMERIK_CALL = re.compile(rf"(CYCLE9[0-9][0-9])\(((?:{_NUM})?(?:,(?:{_NUM})?)*)\)"
                             r"|L[1-9][0-9]{0,6}")
_LINUXCNC_PROBE = (re.compile(rf"G38\.2 Z{_NUM} F{_NUM}"),
                   re.compile(r"#<_compd_z0> = #5063"),
                   re.compile(r"M68 E0 Q\[\[#5063 - #<_compd_z0>\] \* 1000\]"),
                   re.compile(r"M68 E1 Q[0-9]+"))


def _comment_errors(text: str, n: int) -> list[str]:
    inner = text.strip().upper()
    errors = []
    if any(c in text for c in "();%"):
        errors.append(f"line {n}: a parenthesis, ';' or '%' inside a comment")
    if inner.startswith(COMMAND_WORDS) or inner.startswith(SINUMERIK_MARKERS):
        errors.append(f"line {n}: a comment that starts as a command: {text.strip()[:30]!r}")
    return errors


def _split(line: str, dialect: str, n: int) -> tuple[str, list[str]]:
    """The block without its comments, and the errors in them."""
    errors: list[str] = []
    if dialect == "sinumerik":
        body, _, comment = line.partition(";")
        if _:
            errors += _comment_errors(comment, n)
        return body.strip(), errors
    if ";" in line:
        errors.append(f"line {n}: ';' in a {dialect} program")
    body = ""
    rest = line
    while "(" in rest:
        before, _, after = rest.partition("(")
        inner, close, rest = after.partition(")")
        if not close:
            return "", [*errors, f"line {n}: a comment is not closed"]
        body += before
        errors += _comment_errors(inner, n)
    return (body + rest).strip(), errors


def check(program: str, dialect: str) -> Effects:
    """The program's errors and effects (see the module)."""
    rules = {"fanuc": _FANUC, "sinumerik": _SINUMERIK, "linuxcnc": _LINUXCNC}[dialect]
    fx = Effects()
    state: dict[str, str] = {}  # the modal groups known: none at the start

    def relied_on(n: int) -> None:
        wrong = sorted(g for g, v in rules.required.items() if state.get(g) != v)
        if wrong:
            fx.errors.append(f"line {n}: a move or the spindle with modal state not set: "
                             f"{', '.join(wrong)}")

    lines = program.split("\n")
    for n, text in enumerate(lines, 1):
        line = text
        if dialect == "fanuc" and (line == "%" or (n == 2 and re.match(r"O[0-9]{4}\b", line))):
            line = line[5:] if n == 2 else ""  # the record's ends, the program number
        body, errors = _split(line, dialect, n)
        fx.errors += errors
        if not body:
            continue
        words = body.split()
        if all(w in rules.groups for w in words):
            groups = [rules.groups[w] for w in words]
            if len(set(groups)) != len(groups):
                fx.errors.append(f"line {n}: two G codes of one group: {body}")
            state.update({rules.groups[w]: w for w in words})
        elif words[0] == rules.rapid and len(words) > 1 and all(
                re.fullmatch(rf"[XYZ]{_NUM}", w) for w in words[1:]):
            relied_on(n)
            fx.axes |= {w[0] for w in words[1:]}
        elif (m := rules.spindle.fullmatch(body)) is not None:
            relied_on(n)
            fx.speeds.append(int(m.group(1)))
        elif body == rules.stop or rules.dwell.fullmatch(body) or body in rules.end:
            pass
        elif dialect == "fanuc" and _FANUC_CALL.fullmatch(body):
            addresses = [w[0] for w in words[2:]]
            if len(set(addresses)) != len(addresses):
                fx.errors.append(f"line {n}: an argument twice: {body}")
            fx.calls.append(body)
            state.clear()  # the macro's state is its own
        elif dialect == "sinumerik" and _SINUMERIK_CALL.fullmatch(body):
            fx.calls.append(body)
            state.clear()
        elif dialect == "linuxcnc" and any(p.fullmatch(body) for p in _LINUXCNC_PROBE):
            if body.startswith("G38.2"):
                relied_on(n)
                fx.axes.add("Z")
        else:
            fx.errors.append(f"line {n}: a block compd plan does not write: {body[:60]!r}")
    if lines[-1] != "" or not any(w in rules.end for w in program.split()):
        fx.errors.append("the program does not end as its dialect ends one")
    return fx
