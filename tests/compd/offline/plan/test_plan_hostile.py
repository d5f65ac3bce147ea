"""`compd plan` against hostile file names and probe calls, and the modal state
its programs set.

The programs hold no text the user typed: a file name is not written (the
header says where the recorder settings are by what they are), the probe
call is written from its parsed value, every comment is plain
(`compd.offline.plan.comments`). Checked two ways, apart from the generator:
LinuxCNC's own interpreter (``rs274 -g``, skipped when not installed) runs
every LinuxCNC program and must make no canonical call but a plan's
(tests/compd/offline/plan/plan_hostile.py: no MESSAGE, LOGOPEN, PRINT or Python, rpm not
surface speed, no axis that was not named), and a pure-Python check of every
dialect's blocks (tests/compd/offline/plan/plan_safety.py: only compd plan's blocks, no
comment that starts as a command, every modal group set before a move and
after every call of the user's cycle), with the manuals' grammar
(tests/compd/offline/plan/plan_grammar.py) for FANUC and SINUMERIK. The fuzzers are seeded:
the same cases on every run (counts in the constants; ``pytest -s`` prints
them).
"""

from __future__ import annotations

import random
import re
import tomllib
from pathlib import Path

import pytest

from compd.cli import main
from compd.offline.plan.dialects import Fanuc, LinuxCNC, Sinumerik
from compd.sysexits import EX_USAGE
from tests.compd.offline.plan.plan_grammar import check_fanuc, check_sinumerik
from tests.compd.offline.plan.plan_hostile import (
    COMMENT_COMMANDS,
    FANUC_VALID,
    RS274,
    SINUMERIK_VALID,
    Run,
    calls_of,
    canon_errors,
    hostile_calls,
    hostile_names,
    run_rs274,
)
from tests.compd.offline.plan.plan_safety import check

needs_rs274 = pytest.mark.skipif(RS274 is None, reason="rs274 (Debian linuxcnc-uspace) is not "
                                                       "installed")
#: file names tried per dialect (LinuxCNC's each run by rs274 too), probe calls per dialect
NAMES_PER_DIALECT = 120
CALLS_PER_DIALECT = 400
SPEEDS = {1000.0, 2000.0}
GRAMMAR = {"fanuc": check_fanuc, "sinumerik": check_sinumerik}


def _argv(dialect: str, out: Path, call: str | None = None) -> list[str]:
    argv = ["plan", "--hours", "1", "--speeds", "1000,2000", "--probe-every-min", "30",
            "--safe-position", "Z=100", "--dialect", dialect, "-o", str(out)]
    if dialect == "linuxcnc":
        return [*argv, "--probe-at", "Z=20"]
    return [*argv, "--probe-call", call or (FANUC_VALID if dialect == "fanuc" else
                                            SINUMERIK_VALID)[0]]


def _python_errors(text: str, dialect: str) -> list[str]:
    fx = check(text, dialect)
    errors = fx.errors + (GRAMMAR[dialect](text) if dialect in GRAMMAR else [])
    if fx.axes != {"Z"}:
        errors.append(f"axes moved: {sorted(fx.axes)}, only Z named")
    if not set(fx.speeds) <= {1000, 2000}:
        errors.append(f"speeds {fx.speeds}: not the plan's")
    return errors


# -- file names -----------------------------------------------------------------------------


@needs_rs274
@pytest.mark.parametrize("command", ["LOGOPEN,victim.ini", "MSG,pwned", "ABORT,stopped",
                                     "PROBEOPEN victim.ini", "PY,open('victim.ini','w')"])
def test_a_file_name_that_holds_a_comment_command_is_not_run(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], command: str) -> None:
    """The name wrapped across comment lines put ``(LOGOPEN,victim.ini)`` at a
    line's start, and rs274 opened (and truncated) victim.ini."""
    name = f"{'a' * 60} {command} {'b' * 40}.ngc".replace("/", "_")
    out = tmp_path / name
    assert main(_argv("linuxcnc", out)) == 0
    capsys.readouterr()
    text = out.read_text(encoding="ascii")
    [run] = run_rs274([out])
    assert canon_errors(run, text, SPEEDS, {"Z"}) == []
    assert not (tmp_path / "victim.ini").exists()
    word = re.split(r"[ ,]", command, maxsplit=1)[0]
    assert word not in text.upper()  # the name is not written


@needs_rs274
def test_comment_text_of_any_kind_is_a_plain_comment_to_linuxcnc(tmp_path: Path) -> None:
    """The comment writer itself, given hostile text: rs274 reads only COMMENTs."""
    rng = random.Random(3)
    texts = [*COMMENT_COMMANDS, *(f"({c})" for c in COMMENT_COMMANDS),
             *(f"  {c}" for c in COMMENT_COMMANDS), *hostile_names(rng, 300), "", " ", "-"]
    program = tmp_path / "comments.ngc"
    program.write_text("\n".join(LinuxCNC().comment(t) for t in texts) + "\nM2\n",
                       encoding="ascii")
    [run] = run_rs274([program])
    assert canon_errors(run, program.read_text(encoding="ascii"), set(), set()) == []
    assert sum(n == "COMMENT" for n, _ in calls_of(run)) == len(texts)
    for dialect in (LinuxCNC(), Fanuc(), Sinumerik()):
        end = "M2" if dialect.name == "linuxcnc" else "M30"
        lines = "\n".join(dialect.comment(t) for t in texts) + f"\n{end}\n"
        assert check(lines, dialect.name).errors == [], dialect.name
    print(f"\ncomment texts run by rs274 and checked per dialect: {len(texts)}")


@pytest.mark.parametrize("dialect", ["linuxcnc", "fanuc", "sinumerik"])
def test_hostile_file_names_fuzzed(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                   dialect: str) -> None:
    """Every name is written (printable names are all taken) into a program that
    passes the pure-Python check (and the grammar) and, for LinuxCNC, rs274;
    the recorder settings beside it are TOML that names the database."""
    names = hostile_names(random.Random(11 + len(dialect)), NAMES_PER_DIALECT)
    programs: list[Path] = []
    for k, name in enumerate(names):
        out = tmp_path / str(k) / name
        out.parent.mkdir()
        assert main(_argv(dialect, out)) == 0, name
        text = out.read_text(encoding="ascii")
        assert _python_errors(text, dialect) == [], name
        fragment = (out.parent / f"{out.stem}.recorder.toml").read_text(encoding="utf-8")
        assert tomllib.loads(fragment)["recorder"]["path"] == f"{out.stem}.sqlite"
        programs.append(out)
    capsys.readouterr()
    if dialect == "linuxcnc" and RS274 is not None:
        runs = run_rs274(programs)
        for path, run in zip(programs, runs, strict=True):
            text = path.read_text(encoding="ascii")
            assert canon_errors(run, text, SPEEDS, {"Z"}) == [], path.name
        assert not list(tmp_path.rglob("victim*"))
    with capsys.disabled():
        print(f"\n{dialect}: {len(names)} hostile names, each checked by the grammar "
              f"validator{' and rs274' if dialect == 'linuxcnc' and RS274 else ''}")


# -- probe calls ----------------------------------------------------------------------------


@pytest.mark.parametrize(("dialect", "call"), [
    ("sinumerik", "CYCLE978(0,1) G0 X-900 Y-900 Z-900 ()"),
    ("sinumerik", "CYCLE978() M3 S30000 G0 Z-200 A90 ()"),
    ("sinumerik", "CYCLE800(1,0,0)"),  # swivels the head
    ("sinumerik", "PUTFTOC(1,1,1)"),  # writes a tool's fine offset
    ("sinumerik", "CYCLE978(0,1); MSG"),
    ("sinumerik", 'CYCLE978("x")'),
    ("sinumerik", "MCALL CYCLE978(1)"),
    ("sinumerik", "Z100"),
    ("sinumerik", "M30"),
    ("fanuc", "M03 S30000"),
    ("fanuc", "G91 G00 Z-100."),
    ("fanuc", "M99"),
    ("fanuc", "G10 L2 P1 Z-100."),
    ("fanuc", "O2000"),
    ("fanuc", "G65 P9810 G91"),
    ("fanuc", "G65 P9810 L999"),
    ("fanuc", "G65 P1000"),  # the program itself (--program-number 1000)
    ("fanuc", "G65 P9810 (MSG,HI)"),
    ("fanuc", "G65 P9810 Z-10 F500."),  # Z-10 would be -0.01 mm in IS-B
    ("fanuc", "G65 P9810 Z-10. Z-5."),
    ("fanuc", "G66 P9810 Z-10."),
])
def test_a_probe_call_with_anything_but_one_call_is_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], dialect: str, call: str) -> None:
    out = tmp_path / "p.nc"
    assert main(_argv(dialect, out, call)) == EX_USAGE
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("compd plan: --probe-call ")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(("dialect", "call", "block"), [
    ("fanuc", "G65 P9810 Z-10. F500.", "G65 P9810 Z-10. F500."),
    ("fanuc", "  G065  P0123 Z+10.50 S3 Q-0. ", "G65 P123 Z10.50 S3 Q0."),
    # in a G65 block every address but G, L, N, O, P is an argument (M #13, S #19)
    ("fanuc", "G65 P9810 Z-10. M03 S30000", "G65 P9810 Z-10. M3 S30000"),
    ("sinumerik", "CYCLE978(0,1,,1,-10,100,,3,1)", "CYCLE978(0,1,,1,-10,100,,3,1)"),
    ("sinumerik", " CYCLE978( 0 , +1.50,, -.5 ) ", "CYCLE978(0,1.50,,-0.5)"),
    ("sinumerik", "L9810", "L9810"),
])
def test_a_probe_call_is_written_from_its_parsed_value(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], dialect: str, call: str,
        block: str) -> None:
    out = tmp_path / "p.nc"
    assert main(_argv(dialect, out, call)) == 0
    text = out.read_text(encoding="ascii")
    fx = check(text, dialect)
    assert fx.errors == [] and set(fx.calls) == {block} and len(fx.calls) == 3


@pytest.mark.parametrize("dialect", ["fanuc", "sinumerik"])
def test_hostile_probe_calls_fuzzed(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                    dialect: str) -> None:
    """Each call is refused in one line with nothing written, or written as one
    call of a macro or measuring cycle with numbers, in a program that passes
    the pure-Python check and the grammar (only Z moved, the plan's speeds)."""
    calls = hostile_calls(random.Random(5 + len(dialect)), dialect, CALLS_PER_DIALECT)
    taken = 0
    for k, call in enumerate(calls):
        out = tmp_path / f"{k}.nc"
        rc = main(_argv(dialect, out, call))
        err = capsys.readouterr().err
        if rc == EX_USAGE:
            assert err.count("\n") == 1 and "--probe-call" in err, (call, err)
            assert not out.exists()
            continue
        assert rc == 0, (call, err)
        taken += 1
        text = out.read_text(encoding="ascii")
        assert _python_errors(text, dialect) == [], call
        assert len(check(text, dialect).calls) == 3  # one call per measuring cycle
    assert 0 < taken < len(calls)
    with capsys.disabled():
        print(f"\n{dialect}: {len(calls)} hostile probe calls, {len(calls) - taken} refused, "
              f"{taken} written and checked by the grammar validator")


# -- modal state ----------------------------------------------------------------------------


@needs_rs274
def test_modal_state_left_by_another_program_is_set_again(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A program before this one left inches, incremental moves, G55 with an
    offset, inverse time, the XZ plane, diameter mode and a constant surface
    speed with no bound: the plan's moves still go to its millimetres in G54
    and its S words are rpm."""
    out = tmp_path / "warmup.ngc"
    argv = _argv("linuxcnc", out)
    argv[argv.index("Z=100")] = "X=10,Z=100"
    assert main(argv) == 0
    text = out.read_text(encoding="ascii")
    left = tmp_path / "after.ngc"
    left.write_text("G10 L2 P2 X7 Z50\nG20 G91 G55 G93 G18 G7 G96 D100000 S50\n" + text,
                    encoding="ascii")
    [whole] = run_rs274([left])
    lines = whole.stdout.splitlines()
    first = next(k for k, line in enumerate(lines) if 'COMMENT("compd plan' in line)
    run = Run(whole.returncode, "\n".join(lines[first:]), whole.stderr)  # the plan's calls
    assert canon_errors(run, text, SPEEDS, {"X", "Z"}) == []
    moves = [[float(v) for v in a.split(",")[:3]]
             for n, a in calls_of(run) if n in ("STRAIGHT_TRAVERSE", "STRAIGHT_PROBE")]
    # X from where the machine stood to 10 mm (not 5: diameter; 17: G55; 254: inches)
    assert {m[0] for m in moves} == {0.0, 10.0} and {m[2] for m in moves} == {100.0, 20.0, 10.0}
    speeds = [n for n, _ in calls_of(run) if n in ("SET_SPINDLE_MODE", "START_SPINDLE_CLOCKWISE")]
    assert speeds.index("SET_SPINDLE_MODE") < speeds.index("START_SPINDLE_CLOCKWISE")


@pytest.mark.parametrize(("dialect", "modal"), [
    ("fanuc", ["G21", "G15 G17 G40 G50 G69", "G67 G80 G90 G94 G97", "G54"]),
    ("sinumerik", ["G17 G40 G71 G90 G94", "G54"]),
])
def test_modal_state_is_set_at_the_start_and_after_every_call(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], dialect: str,
        modal: list[str]) -> None:
    out = tmp_path / "p.nc"
    assert main(_argv(dialect, out)) == 0
    lines = out.read_text(encoding="ascii").split("\n")
    blocks = [line for line in lines if line and not line.startswith(("(", ";", "%"))]
    start = 1 if dialect == "fanuc" else 0  # after O1000
    assert blocks[start:start + len(modal)] == modal
    calls = [k for k, b in enumerate(blocks) if b.startswith(("G65", "CYCLE"))]
    assert len(calls) == 3
    for k in calls:
        assert blocks[k + 1:k + 1 + len(modal)] == modal
        assert blocks[k + 1 + len(modal)].startswith(("G00 Z", "G0 Z"))
    # the check refuses the program without the blocks after a call
    cut = "\n".join(b for k, b in enumerate(blocks) if not any(
        c < k <= c + len(modal) for c in calls)) + "\n"
    assert any("modal state not set" in e for e in check(cut, dialect).errors)
