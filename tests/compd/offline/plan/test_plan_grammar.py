"""`compd plan`'s FANUC and SINUMERIK programs against their manuals' grammar
(tests/compd/offline/plan/plan_grammar.py), and the grammar against programs it must refuse:
a check that passes everything checks nothing."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from compd.cli import main
from tests.compd.offline.plan.plan_grammar import check_fanuc, check_sinumerik

FANUC_CALL = "G65 P9810 Z-10. F500."
SINUMERIK_CALL = "CYCLE978(0,1,,1,-10,100,,3,1)"

#: option sets over the dialects' corners: no motion, probing, long steps split, odd hours
CASES = [
    ["--hours", "24", "--speeds", "1250,2500,5000"],
    ["--hours", "24", "--speeds", "2000,4000,8000", "--rest-h", "3", "--probe-every-min", "15",
     "--safe-position", "Z=150"],
    ["--hours", "168", "--speeds", "6000", "--probe-every-min", "90",
     "--safe-position", "X=0,Y=0,Z=250.5", "--probe-at", "X=-120.25,Y=40,Z=30"],
    ["--hours", "0.37", "--speeds", "300,12000,7", "--probe-every-min", "1",
     "--safe-position", "Z=10", "--spindle-stop-s", "0"],
]


def _plan(tmp_path: Path, dialect: str, argv: list[str], name: str) -> str:
    out = tmp_path / name
    call = FANUC_CALL if dialect == "fanuc" else SINUMERIK_CALL
    extra = ["--probe-call", call] if "--probe-every-min" in argv else []
    assert main(["plan", *argv, *extra, "--dialect", dialect, "-o", str(out)]) == 0
    return out.read_text(encoding="ascii")


@pytest.mark.parametrize("argv", CASES, ids=range(len(CASES)))
def test_fanuc_programs_pass_the_grammar(tmp_path: Path, argv: list[str]) -> None:
    text = _plan(tmp_path, "fanuc", argv, "O1000.nc")
    assert check_fanuc(text) == []
    dwells = [float(x) for x in re.findall(r"^G04 X([\d.]+)$", text, re.M)]
    total = float(re.search(r"DWELL IN ALL: ([\d.]+) S", text.replace("\n", " ")
                            .replace(") (", " ")).group(1))  # type: ignore[union-attr]
    assert sum(dwells) == pytest.approx(total, abs=1e-6)
    assert max(dwells) <= 9999.0  # split where IS-C would refuse


@pytest.mark.parametrize("argv", CASES, ids=range(len(CASES)))
def test_sinumerik_programs_pass_the_grammar(tmp_path: Path, argv: list[str]) -> None:
    text = _plan(tmp_path, "sinumerik", argv, "WARMUP.MPF")
    assert check_sinumerik(text) == []
    assert "G71" in text and "G21" not in text  # metric in the native language


@pytest.mark.parametrize(("dialect", "check"), [("fanuc", check_fanuc),
                                               ("sinumerik", check_sinumerik)])
def test_a_file_name_of_any_letters_keeps_the_program_valid(tmp_path: Path, dialect: str,
                                                            check: object) -> None:
    text = _plan(tmp_path, dialect, CASES[1], "Wärmegang (Halle 3); 50%.nc")
    assert check(text) == []  # type: ignore[operator]
    assert text.isascii()


@pytest.fixture
def fanuc(tmp_path: Path) -> str:
    return _plan(tmp_path, "fanuc", CASES[1], "O1000.nc")


@pytest.fixture
def sinumerik(tmp_path: Path) -> str:
    return _plan(tmp_path, "sinumerik", CASES[1], "WARMUP.MPF")


@pytest.mark.parametrize(("old", "new", "why"), [
    ("G00 Z150.0", "G00 Z150", "no decimal point"),
    ("G04 X900.0", "G04 X3600.0 M05", "G04 must stand alone"),
    ("G04 X900.0", "G04 X12000.0", "above 9999.9999"),
    ("S2000 M03", "S2000.5 M03", "S takes no decimal point"),
    ("S2000 M03", "S2000 M03 M08", "more than one M"),
    ("G00 Z150.0", "G38.2 Z150.0", "G takes no decimal point"),
    ("G00 Z150.0", "G38 Z150.0", "not a FANUC G code"),
    ("G00 Z150.0", "G00 Z150.0 Z10.0", "Z twice"),
    ("\nG54\n", "\nG54 (a comment)\n", "characters outside"),
    ("\nG54\n", "\nG54 (NESTED (COMMENT))\n", "parenthesis inside a comment"),
    ("\nG54\n", "\nG54 (OPEN\n", "not closed"),
    ("\nG54\n", "\nG54 X123456789.0\n", "more than 8 digits"),
    ("\nG54\n", "\nG54 (" + "X" * 130 + ")\n", "characters (at most 128)"),
    ("\nG54\n", "\nG54 50%\n", "'%' ends the record"),
    ("O1000", "O0", "program number"),
    ("M30\n%", "M05\n%", "must end the program"),
])
def test_the_fanuc_grammar_refuses(fanuc: str, old: str, new: str, why: str) -> None:
    assert old in fanuc
    errors = check_fanuc(fanuc.replace(old, new, 1))
    assert errors and any(why in e for e in errors), errors


def test_the_fanuc_grammar_refuses_a_file_without_its_percent_signs(fanuc: str) -> None:
    assert check_fanuc(fanuc.removeprefix("%\n"))
    assert check_fanuc(fanuc.removesuffix("%\n"))


@pytest.mark.parametrize(("old", "new", "why"), [
    ("G71 G90", "G21 G90", "not a G function of SINUMERIK's native"),
    ("G4 F900.0", "G4 F5400.0 M5", "G4 must stand alone"),
    ("G4 F900.0", "G4 X900.0", "G4 must stand alone"),
    ("\nG54\n", "\nG54 (COMMENT)\n", "parentheses outside a call"),
    ("S2000 M3", "S-2000 M3", "negative spindle speed"),
    ("S2000 M3", "S2000 M3 M8 M9 M10 M11 M12", "more than 5 M"),
    ("\nG54\n", "\nG54 ZZ\n", "not a word"),
    ("\nG54\n", "\nG54 ;" + "x" * 520 + "\n", "at most 512"),
    ("\nG54\n", "\nG54 \u00b5\n", "outside printable ASCII"),
    ("\nM30\n", "\nM5\n", "must end with M30"),
])
def test_the_sinumerik_grammar_refuses(sinumerik: str, old: str, new: str, why: str) -> None:
    assert old in sinumerik
    errors = check_sinumerik(sinumerik.replace(old, new, 1))
    assert errors and any(why in e for e in errors), errors


@pytest.mark.parametrize(("dialect", "call"), [
    ("fanuc", "G65 P9810 Z-10 F500."),  # Z-10 would be -0.01 mm in IS-B
    ("fanuc", "g65 p9810"),
    ("fanuc", "G65 P9810 (PROBE)"),
    ("sinumerik", "CYCLE978(0,1); probe"),
    ("sinumerik", "9CYCLE"),
])
def test_plan_refuses_a_probe_call_its_dialect_cannot_take(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], dialect: str, call: str) -> None:
    out = tmp_path / "p.nc"
    rc = main(["plan", "--hours", "8", "--speeds", "1000", "--dialect", dialect, "-o", str(out),
               "--probe-every-min", "30", "--safe-position", "Z=100", "--probe-call", call])
    err = capsys.readouterr().err
    assert rc == 64 and err.count("\n") == 1 and "--probe-call" in err
    assert not out.exists()
