"""`compd plan --traverse AXIS --positions … --duties …`: the traverse experiment of a
position-dependent calibration, its schedule's time, its duty, its measuring
passes, the grammar of each dialect, and its refusals."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from compd.cli import main
from compd.config.loader import load_config
from compd.sysexits import EX_USAGE
from tests.compd.offline.plan.plan_grammar import check_fanuc, check_sinumerik
from tests.compd.offline.plan.plan_hostile import RS274, calls_of, run_rs274
from tests.configs import write_config

BASE = ["--traverse", "X", "--positions", "0,250,500,750,1000", "--duties", "25,50,90",
        "--hours", "6", "--probe-every-min", "30", "--safe-position", "Z=100", "--feed",
        "10000"]
CALLS = {"fanuc": "G65 P9810 X0. F500.", "sinumerik": "CYCLE978(0,1,,1,-10,100,,3,1)"}


def _plan(tmp_path: Path, argv: list[str], name: str = "tr.ngc") -> str:
    out = tmp_path / name
    assert main(["plan", *argv, "-o", str(out)]) == 0
    return out.read_text(encoding="ascii")


def _blocks(text: str) -> list[str]:
    return [ln for ln in text.splitlines() if ln and not ln.startswith("(")]


def test_moves_and_dwells_add_up_to_the_schedule_at_each_duty(tmp_path: Path) -> None:
    text = _plan(tmp_path, [*BASE, "--dialect", "linuxcnc"])
    blocks = _blocks(text)
    moving_s = 2 * 1000 / 10000 * 60  # one cycle's two feed moves: 12 s
    feeds = [b for b in blocks if b.startswith("G1 ")]
    dwells = [float(b.split("P")[1]) for b in blocks if b.startswith("G4 P")]
    passes = text.count("(measuring pass ")
    assert passes == 6 * 2 + 1  # every 30 min of 6 h, the start and the end
    stops = [b for b in blocks if b.startswith("G0 X")]
    assert len(stops) == 5 * passes
    # every feed move is a full stroke: the schedule's time is the moves and the
    # dwells, less the standstills of the passes (10 s at each of 5 positions)
    schedule_s = len(feeds) / 2 * moving_s + sum(dwells) - passes * 5 * 10.0
    assert schedule_s == pytest.approx(6 * 3600.0, abs=1e-6)
    # within a duty step, each cycle's moves take the duty's share of the cycle
    for duty, pause in ((25, "36.0"), (50, "12.0"), (90, "1.333")):
        assert f"traverse cycles at {duty} percent duty" in text
        assert moving_s / (moving_s + float(pause)) == pytest.approx(duty / 100, abs=1e-3)
        assert f"G1 X0.0\nG4 P{pause}\n" in text
    assert set(feeds) == {"G1 X1000.0 F10000.0", "G1 X1000.0", "G1 X0.0"}
    assert "M3" not in text and "S" not in "".join(b for b in blocks if b[0] != "G")


def test_each_pass_stops_at_every_position_in_order(tmp_path: Path) -> None:
    text = _plan(tmp_path, [*BASE, "--dialect", "linuxcnc", "--stop-s", "7.5"])
    first = text.split("(measuring pass 1 of 13 at 0.00 h)\n")[1].split("(")[0]
    assert first.split("\n")[:10] == ["G0 X0.0", "G4 P7.5", "G0 X250.0", "G4 P7.5",
                                      "G0 X500.0", "G4 P7.5", "G0 X750.0", "G4 P7.5",
                                      "G0 X1000.0", "G4 P7.5"]
    # Z goes to the safe height before anything moves, and back there at the end
    blocks = _blocks(text)
    assert blocks.index("G0 Z100.0") < blocks.index("G0 X0.0")
    assert blocks[-2:] == ["G0 Z100.0", "M2"]


@pytest.mark.parametrize("dialect", ["fanuc", "sinumerik"])
def test_the_programs_pass_their_dialects_grammar(tmp_path: Path, dialect: str) -> None:
    argv = [*BASE, "--dialect", dialect, "--probe-call", CALLS[dialect],
            "--safe-position", "Z=100,Y=-20.5"]
    text = _plan(tmp_path, argv, f"tr.{dialect}")
    check = check_fanuc if dialect == "fanuc" else check_sinumerik
    assert check(text) == []
    # after each call of the user's cycle: the modal state again, then Z to safety
    call = CALLS[dialect]
    after = text.split(call + "\n")[1].splitlines()
    modal = 4 if dialect == "fanuc" else 2
    assert after[modal] in ("G00 Z100.", "G00 Z100.0", "G0 Z100.0")
    assert text.splitlines().count(call) == 5 * 13


def test_the_linuxcnc_program_runs_in_its_interpreter(tmp_path: Path) -> None:
    if RS274 is None:
        pytest.skip("rs274 (Debian linuxcnc-uspace) is not installed")
    _plan(tmp_path, [*BASE, "--hours", "2", "--dialect", "linuxcnc",
                     "--safe-position", "X=0,Y=40,Z=100"])
    run = run_rs274([tmp_path / "tr.ngc"])[0]
    assert run.returncode == 0, run.stderr
    calls = calls_of(run)
    names = {n for n, _ in calls}
    assert {"STRAIGHT_FEED", "STRAIGHT_TRAVERSE", "DWELL", "PROGRAM_END"} <= names
    assert not names & {"MESSAGE", "START_SPINDLE_CLOCKWISE", "STRAIGHT_PROBE"}
    moves = [tuple(float(v) for v in args.split(",")[:3]) for name, args in calls
             if name in ("STRAIGHT_FEED", "STRAIGHT_TRAVERSE")]
    assert moves[:2] == [(0.0, 0.0, 100.0), (0.0, 40.0, 100.0)]  # Z up first, then X, Y
    for x, y, z in moves[2:]:  # then X alone, along the travel, at the safe Y and Z
        assert 0.0 <= x <= 1000.0 and y == 40.0 and z == 100.0


def test_the_recorder_settings_name_a_column_per_position(tmp_path: Path) -> None:
    _plan(tmp_path, [*BASE, "--dialect", "linuxcnc"])
    side = (tmp_path / "tr.recorder.toml").read_text(encoding="utf-8")
    for x in (0, 250, 500, 750, 1000):
        assert f'# [channels."dx_at_{x}mm_um"]' in side
    assert "--positions --reference-position-mm 0.0 --column slope_um_m" in side
    assert "(linuxcnc; 6 h of schedule, 13 measuring passes, every 30 min)" in side
    assert "dz_um" not in side


@pytest.mark.parametrize(("extra", "says"), [
    (["--speeds", "1000"], "--speeds goes without --traverse"),
    (["--probe-at", "Z=5"], "--probe-at goes without --traverse"),
    (["--time-scale", "10"], "--time-scale goes without --traverse"),
    (["--dialect", "linuxcnc", "--probe-call", "G65 P1"], "--probe-call is for"),
    (["--positions", "5"], "two or more distinct positions"),
    (["--positions", "0,20000"], "within ±10000 mm"),
    (["--duties", "0,50"], "1 … 100"),
    (["--duties", "50,50"], "given twice"),
    (["--duties", "12.5"], "whole percent"),
    (["--feed", "0"], "--feed"),
    (["--safe-position", "X=5"], "Z to retract to"),
    (["--hours", "0.001"], "no time for the 6 duty steps"),
    (["--positions", "0,0.5", "--feed", "60000", "--duties", "1,100", "--hours", "168"],
     "blocks"),
])
def test_a_bad_traverse_is_one_line_and_exit_64(tmp_path: Path, extra: list[str], says: str,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    argv = [*BASE, "--dialect", "fanuc", "--probe-call", CALLS["fanuc"], *extra]
    try:
        code = main(["plan", *argv, "-o", str(tmp_path / "x.nc")])
    except SystemExit as exc:  # argparse's own refusal
        code = int(str(exc.code))
    assert code == EX_USAGE
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0], err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(("argv", "says"), [
    (["--positions", "0,100", "--hours", "1", "--speeds", "100"], "--positions goes with"),
    (["--traverse", "X", "--hours", "1", "--duties", "5"], "--traverse needs --positions"),
    (["--hours", "1"], "--speeds is required"),
])
def test_traverse_options_go_together(tmp_path: Path, argv: list[str], says: str,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["plan", *argv, "--dialect", "linuxcnc", "-o", str(tmp_path / "x.ngc")])
    assert code == EX_USAGE
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0], err


def test_a_hostile_probe_call_never_reaches_the_program(tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]
                                                        ) -> None:
    for call in ("G65 P9810 X0. G10", "G65 P9810 (MSG,x)", "CYCLE978(0) G0 X-900",
                 "CYCLE800(1)"):
        dialect = "sinumerik" if call.startswith("CYCLE") else "fanuc"
        code = main(["plan", *BASE, "--dialect", dialect, "--probe-call", call,
                     "-o", str(tmp_path / "x.nc")])
        assert code == EX_USAGE
        assert len(capsys.readouterr().err.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []
    # the comments hold no text a controller would act on
    text = _plan(tmp_path, [*BASE, "--dialect", "linuxcnc"])
    for comment in re.findall(r"\(([^()]*)\)", text):
        assert not comment.lstrip().upper().startswith(("MSG", "LOG", "PY", "DEBUG", "ABORT"))


def test_with_the_machines_config_the_recorder_settings_run_as_they_are(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    machine = write_config(tmp_path, "modbus://127.0.0.1:5020")
    _plan(tmp_path, [*BASE, "--dialect", "linuxcnc", "--config", str(machine)])
    path = tmp_path / "tr.recorder.toml"
    loaded = load_config(path)
    assert loaded.recorder_only and not loaded.outputs
    assert loaded.channels == load_config(machine).channels
    text = path.read_text(encoding="utf-8")
    assert "compd run tr.recorder.toml" in text
    assert '# [channels."dx_at_500mm_um"]' in text  # the machine's config has none yet
