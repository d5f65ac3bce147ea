"""Syntax checks for the FANUC and SINUMERIK programs `compd plan` writes, from
their manuals' grammar (no controller to run them here; the LinuxCNC dialect
is checked by LinuxCNC's own interpreter instead, tests/compd/offline/plan/test_plan_rs274.py).

Written apart from compd's generator on purpose: a rule the generator gets
wrong must not be wrong here the same way. Each check returns the list of
errors as "line N: why" (empty: the program passes).

FANUC (Series 0i/16i/30i operator's manuals, program configuration; ISO code):
the file opens and closes with ``%``; the first block is the program number
``O`` with 1-4 digits (not 0); a block is an optional ``/``, an optional
sequence number ``N`` (1-99999), then words (an address letter and a number)
and comments ``( … )`` (no parenthesis inside); characters are ISO code,
upper case (a memory card drops lower case); a number has at most 8 digits;
G, M, S, P (dwell in ms, macro program number), N, O, T, H, D, L take no
decimal point, while a coordinate or feed without one is read in least
increments (``Z100`` = 0.1 mm in IS-B), so ours must carry one; ``G04`` stands
alone in its block with ``X`` (seconds, ≤ 9999.9999 for IS-C) or ``P``;
one M code a block, at most five G codes (a bound of ours, the 0i's); an
address once a block (G codes of different groups apart); ``G20``/``G21``
alone in its block (inch/metric: "an independent block"); the last block
before the closing ``%`` is ``M30`` or ``M02``. A block is at most 128
characters here (a conservative bound of ours: the manuals give none across
series).

SINUMERIK 840D (programming manual, fundamentals; native language): a comment
runs from ``;`` to the end of the line (parentheses are not comments); a block
is at most 512 characters with its comment and LF; a block is an optional
``/``, an optional ``N`` number, then words (an address letter and a number,
or ``ADDR=value``), or one subprogram/cycle call ``NAME`` or ``NAME(args)``
alone; G functions of the native language only (G71/G70 metric/inch: G21/G20
belong to the ISO dialect); ``G4`` stands alone in its block with ``F``
(seconds) or ``S`` (revolutions); at most 5 M functions a block; the program
ends with ``M30``, ``M2`` or ``M17``.
"""

from __future__ import annotations

import re

_NUMBER = r"[+-]?(?:\d+\.?\d*|\.\d+)"

# -- FANUC --------------------------------------------------------------------------------

FANUC_MAX_BLOCK = 128
_FANUC_CHARS = re.compile(r"[A-Z0-9 +\-./*=#\[\],()'?&:]*")
_FANUC_WORD = re.compile(rf"([A-Z])({_NUMBER}|#\d+)")
_FANUC_INTEGER = set("GMSPNOTHDL")
#: the M series (machining centre) G codes; G50/G51 scale there (G50 S is a lathe's)
_FANUC_G = {0, 1, 2, 3, 4, 9, 10, 15, 16, 17, 18, 19, 20, 21, 28, 30, 31, 40, 41, 42, 43,
            44, 49, 50, 51, 52, 53, 54, 55, 56, 57, 58, 59, 65, 66, 67, 68, 69, 80, 81, 82,
            83, 84, 85, 86, 87, 88, 89, 90, 91, 92, 94, 95, 96, 97, 98, 99}
FANUC_MAX_G_A_BLOCK = 5
FANUC_MAX_DWELL_S = 9999.9999


def _digits(value: str) -> int:
    return sum(c.isdigit() for c in value)


def _fanuc_block(text: str) -> tuple[list[tuple[str, str]], list[str]]:
    """The words of one block and the errors in its form."""
    errors: list[str] = []
    rest = text.lstrip()
    if rest.startswith("/"):
        rest = rest[1:]
    words: list[tuple[str, str]] = []
    while rest:
        rest = rest.lstrip()
        if not rest:
            break
        if rest[0] == "(":
            close = rest.find(")")
            if close < 0:
                errors.append("a comment is not closed")
                break
            if "(" in rest[1:close]:
                errors.append("a parenthesis inside a comment")
            rest = rest[close + 1:]
            continue
        if rest[0] == ")":
            errors.append("a ')' outside a comment")
            break
        m = _FANUC_WORD.match(rest)
        if m is None:
            errors.append(f"not a word: {rest.split()[0]!r}")
            break
        words.append((m.group(1), m.group(2)))
        rest = rest[m.end():]
    return words, errors


def _fanuc_words(words: list[tuple[str, str]]) -> list[str]:
    errors = []
    seen: set[str] = set()
    gs: set[str] = set()
    for address, value in words:
        if value.startswith("#"):
            continue
        if _digits(value) > 8:
            errors.append(f"{address}{value}: more than 8 digits")
        if address in _FANUC_INTEGER and "." in value:
            errors.append(f"{address}{value}: {address} takes no decimal point")
        if address not in _FANUC_INTEGER and "." not in value:
            errors.append(f"{address}{value}: no decimal point (read in least increments)")
        if address == "G":
            if "." not in value and int(value) not in _FANUC_G:
                errors.append(f"G{value}: not a FANUC G code")
            if value in gs:
                errors.append(f"G{value} twice in a block")
            gs.add(value)
        elif address in seen:
            errors.append(f"{address} twice in a block")
        if address == "S" and value.startswith("-"):
            errors.append(f"S{value}: a negative spindle speed")
        seen.add(address)
    if sum(a == "M" for a, _ in words) > 1:
        errors.append("more than one M code in a block")
    if sum(a == "G" for a, _ in words) > FANUC_MAX_G_A_BLOCK:
        errors.append(f"more than {FANUC_MAX_G_A_BLOCK} G codes in a block")
    if any(a == "G" and v in ("20", "21") for a, v in words) and len(words) > 1:
        errors.append("G20/G21 stands alone in its block")
    if any(a == "G" and v.lstrip("0") == "4" for a, v in words):
        others = [a for a, v in words if not (a == "G" and v.lstrip("0") == "4")]
        if len(others) != 1 or others[0] not in ("X", "P"):
            errors.append("G04 must stand alone with one X or P")
        for a, v in words:
            if a == "X" and not v.startswith("#") and float(v) > FANUC_MAX_DWELL_S:
                errors.append(f"G04 X{v}: above {FANUC_MAX_DWELL_S} s (IS-C)")
    return errors


def check_fanuc(program: str) -> list[str]:
    errors: list[str] = []
    if not program.endswith("\n"):
        errors.append("the file does not end with a line feed")
    lines = program.split("\n")
    if lines and lines[-1] == "":
        lines.pop()
    if len(lines) < 4 or lines[0] != "%" or lines[-1] != "%":
        return [*errors, "the program must open and close with a line '%'"]
    number = re.match(r"O(\d{1,4})(?:\s*\(.*\))?$", lines[1])
    if number is None or int(number.group(1)) == 0:
        errors.append(f"line 2: a program number O1-O9999 expected, got {lines[1]!r}")
    last_words: list[tuple[str, str]] = []
    for n, line in enumerate(lines[2:-1], 3):
        if len(line) > FANUC_MAX_BLOCK:
            errors.append(f"line {n}: {len(line)} characters (at most {FANUC_MAX_BLOCK})")
        if "%" in line:
            errors.append(f"line {n}: '%' ends the record inside the program")
        if not _FANUC_CHARS.fullmatch(line):
            bad = sorted({c for c in line if not _FANUC_CHARS.fullmatch(c)})
            errors.append(f"line {n}: characters outside FANUC's ISO set: {bad}")
            continue
        body = line.lstrip("/ ")
        seq = re.match(r"N(\d+)\s*", body)
        if seq is not None:
            if not 1 <= int(seq.group(1)) <= 99999:
                errors.append(f"line {n}: sequence number N1-N99999")
            body = body[seq.end():]
        if body.startswith("O"):
            errors.append(f"line {n}: a program number inside the program")
            continue
        words, form = _fanuc_block(body)
        errors += [f"line {n}: {e}" for e in form + _fanuc_words(words)]
        if words:
            last_words = words
    if ("M", "30") not in last_words and ("M", "02") not in last_words \
            and ("M", "2") not in last_words:
        errors.append("the last block before '%' must end the program: M30 or M02")
    return errors


# -- SINUMERIK ----------------------------------------------------------------------------

SINUMERIK_MAX_BLOCK = 512
_SIN_G = {0, 1, 2, 3, 4, 9, 17, 18, 19, 40, 41, 42, 53, 54, 55, 56, 57, 60, 63, 64, 70, 71,
          74, 75, 90, 91, 93, 94, 95, 96, 97, 153, 500, 505, 506, 507, 599, 700, 710}
_SIN_WORD = re.compile(rf"([A-Z])(={_NUMBER}|{_NUMBER})(?=\s|$)", re.IGNORECASE)
_SIN_CALL = re.compile(r"([A-Z_][A-Z0-9_]+)(\([^()]*\))?$", re.IGNORECASE)


def _sinumerik_block(body: str) -> list[str]:
    errors: list[str] = []
    if _SIN_CALL.match(body) is not None and _SIN_WORD.match(body) is None:
        return errors  # a subprogram or cycle call, alone in its block
    if "(" in body or ")" in body:
        return ["parentheses outside a call NAME(args): a comment is ';' in SINUMERIK"]
    words: list[tuple[str, str]] = []
    rest = body
    while rest:
        m = _SIN_WORD.match(rest)
        if m is None:
            return [*errors, f"not a word: {rest.split()[0]!r}"]
        words.append((m.group(1).upper(), m.group(2).lstrip("=")))
        rest = rest[m.end():].lstrip()
    for address, value in words:
        if address == "G" and ("." in value or int(value) not in _SIN_G):
            errors.append(f"G{value}: not a G function of SINUMERIK's native language")
        if address == "S" and float(value) < 0:
            errors.append(f"S{value}: a negative spindle speed")
    if sum(a == "M" for a, _ in words) > 5:
        errors.append("more than 5 M functions in a block")
    if any(a == "G" and v == "4" for a, v in words):
        others = [a for a, v in words if not (a == "G" and v == "4")]
        if len(others) != 1 or others[0] not in ("F", "S"):
            errors.append("G4 must stand alone with one F (seconds) or S (revolutions)")
    return errors


def check_sinumerik(program: str) -> list[str]:
    errors: list[str] = []
    if not program.endswith("\n"):
        errors.append("the file does not end with a line feed")
    lines = program.split("\n")
    if lines and lines[-1] == "":
        lines.pop()
    last = ""
    for n, line in enumerate(lines, 1):
        if len(line) + 1 > SINUMERIK_MAX_BLOCK:
            errors.append(f"line {n}: {len(line) + 1} characters with LF (at most "
                          f"{SINUMERIK_MAX_BLOCK})")
        if any(not (c.isascii() and (c.isprintable() or c == "\t")) for c in line):
            errors.append(f"line {n}: a character outside printable ASCII")
            continue
        if n == 1 and line.startswith("%_N_"):
            continue
        body = line.split(";", 1)[0].strip()
        if body.startswith("/"):
            body = body[1:].lstrip()
        seq = re.match(r"(?:N|:)\d+\s*", body)
        if seq is not None:
            body = body[seq.end():]
        if not body:
            continue
        errors += [f"line {n}: {e}" for e in _sinumerik_block(body)]
        last = body
    if last.upper() not in ("M30", "M2", "M02", "M17"):
        errors.append("the program must end with M30, M2 or M17")
    return errors
