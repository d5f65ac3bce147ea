"""`compd plan --dialect linuxcnc` run by LinuxCNC's own interpreter: `rs274 -g
FILE` (standalone, from Debian's linuxcnc-uspace) reads the program as the
machine would and prints the canonical calls it makes. The program must run
to PROGRAM_END without an error, and the calls must be the experiment: the
speeds in the designed order, the dwells summing to what the header says, one
STRAIGHT_PROBE per measuring cycle, and no axis moved that the user did not
name."""

from __future__ import annotations

import re
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path

import pytest

from compd.cli import main
from tests.compd.offline.plan.plan_hostile import rs274_env

RS274 = shutil.which("rs274")
pytestmark = pytest.mark.skipif(RS274 is None, reason="rs274 (Debian linuxcnc-uspace) is not "
                                                      "installed")

_CALL = re.compile(r"^\s*\d+ N\.+ ([A-Z_]+)\((.*)\)\s*$")


@dataclass
class Canon:
    calls: list[tuple[str, str]]

    def args(self, name: str) -> list[list[float]]:
        return [[float(x) for x in re.split(r"[ ,]+", a.strip())]
                for n, a in self.calls if n == name]

    def names(self) -> list[str]:
        return [n for n, _ in self.calls]

    def header(self) -> str:
        return " ".join(a.strip('"') for n, a in self.calls if n == "COMMENT")


def _interpret(tmp_path: Path, argv: list[str]) -> Canon:
    tmp_path.mkdir(exist_ok=True)
    out = tmp_path / "warmup.ngc"
    assert main(["plan", *argv, "--dialect", "linuxcnc", "-o", str(out)]) == 0
    assert RS274 is not None
    done = subprocess.run([RS274, "-g", str(out)], cwd=tmp_path, capture_output=True,
                          env=rs274_env(tmp_path / ".rs274-home"), text=True, timeout=600,
                          check=False)
    assert done.returncode == 0, done.stderr
    assert done.stderr.strip() in ("", "executing"), done.stderr  # an error is printed there
    calls = [(m.group(1), m.group(2)) for m in map(_CALL.match, done.stdout.splitlines()) if m]
    assert calls, done.stdout[:500]
    return Canon(calls)


def _segments(canon: Canon, run_down_s: float) -> list[tuple[float, float]]:
    """(rpm, hours) of spindle state as the dwells passed, merged while it stays."""
    speed = turning = 0.0
    segments: list[tuple[float, float]] = []
    for name, args in canon.calls:
        if name == "SET_SPINDLE_SPEED":
            speed = float(args.split(",")[1])
        elif name == "START_SPINDLE_CLOCKWISE":
            turning = speed
        elif name == "STOP_SPINDLE_TURNING":
            turning = 0.0
        elif name == "DWELL" and float(args) != run_down_s:
            if segments and segments[-1][0] == turning:
                segments[-1] = (turning, segments[-1][1] + float(args) / 3600.0)
            else:
                segments.append((turning, float(args) / 3600.0))
    return [(rpm, round(h, 6)) for rpm, h in segments]


def _seconds(header: str, pattern: str) -> float:
    m = re.search(pattern, header)
    assert m is not None, header
    return float(m.group(1))


def test_the_interpreter_runs_the_experiment_with_the_dwells_the_header_says(
        tmp_path: Path) -> None:
    canon = _interpret(tmp_path, [
        "--hours", "24", "--speeds", "5000,1250,2500", "--probe-every-min", "10",
        "--safe-position", "Z=100", "--probe-at", "Z=30", "--probe-depth-mm", "8",
        "--spindle-stop-s", "4"])
    header = canon.header()
    dwells = [a[0] for a in canon.args("DWELL")]
    assert sum(dwells) == pytest.approx(_seconds(header, r"Dwell in all: ([\d.]+) s"),
                                        abs=1e-3)
    schedule_s = _seconds(header, r"rests, ([\d.]+) s of dwell")
    assert schedule_s == 24 * 3600.0
    probes = canon.args("STRAIGHT_PROBE")
    assert len(probes) == 24 * 6 + 1  # at 0, every 10 min, and at the end
    stops = [d for d in dwells if d == 4.0]
    assert sum(dwells) - 4.0 * len(stops) == pytest.approx(schedule_s, abs=1e-3)
    assert all(p[2] == pytest.approx(22.0) for p in probes)  # Z30 down by 8 mm
    counters = [a[1] for a in canon.args("SET_AUX_OUTPUT_VALUE") if a[0] == 1]
    assert counters == [float(k) for k in range(1, len(probes) + 1)]
    # the schedule the spindle saw: a rising staircase, a rest, a falling one, a rest,
    # 3 h each (the run-down dwells of the measuring cycles left out)
    assert _segments(canon, run_down_s=4.0) == [
        (1250.0, 3.0), (2500.0, 3.0), (5000.0, 3.0), (0.0, 3.0),
        (5000.0, 3.0), (2500.0, 3.0), (1250.0, 3.0), (0.0, 3.0)]
    names = canon.names()
    assert "PROGRAM_END" in names and names.index("PROGRAM_END") > names.index("DWELL")
    # nothing but Z moved: X and Y stay where the machine was
    for name in ("STRAIGHT_TRAVERSE", "STRAIGHT_FEED", "STRAIGHT_PROBE"):
        assert all(a[0] == 0.0 and a[1] == 0.0 for a in canon.args(name))


def test_without_a_safe_position_the_program_moves_no_axis(tmp_path: Path) -> None:
    canon = _interpret(tmp_path, ["--hours", "8", "--speeds", "3000,6000"])
    names = set(canon.names())
    assert not names & {"STRAIGHT_TRAVERSE", "STRAIGHT_FEED", "STRAIGHT_PROBE", "ARC_FEED"}
    assert "Axes moved: none" in canon.header()
    assert sum(a[0] for a in canon.args("DWELL")) == pytest.approx(8 * 3600.0, abs=1e-3)
    assert [a[1] for a in canon.args("SET_SPINDLE_SPEED")] == [3000.0, 6000.0, 6000.0, 3000.0]
    assert "STOP_SPINDLE_TURNING" in names and "PROGRAM_END" in names


def test_named_axes_only_and_odd_hours_sum_exactly(tmp_path: Path) -> None:
    canon = _interpret(tmp_path, [
        "--hours", "0.37", "--speeds", "800", "--rest-h", "0.05", "--probe-every-min", "7",
        "--safe-position", "X=10,Z=120", "--probe-at", "X=-45.5,Z=12.25",
        "--spindle-stop-s", "0"])
    assert sum(a[0] for a in canon.args("DWELL")) == pytest.approx(0.37 * 3600.0, abs=1e-3)
    moves = canon.args("STRAIGHT_TRAVERSE") + canon.args("STRAIGHT_PROBE")
    assert {m[0] for m in moves} <= {0.0, 10.0, -45.5}
    assert all(m[1] == 0.0 for m in moves)  # Y never named, never moved
    assert "Axes moved: X, Z only" in canon.header()


def test_a_time_scale_divides_every_dwell_and_the_header_says_so(tmp_path: Path) -> None:
    """--time-scale 120 (a simulated machine at 120 machine seconds per real
    second): the same spindle steps, every dwell divided by 120 (the measuring
    cycles' run-downs too), and a header that says so."""
    argv = ["--hours", "2", "--speeds", "3000,6000,9000", "--probe-every-min", "30",
            "--safe-position", "Z=100", "--probe-at", "Z=30", "--spindle-stop-s", "6"]
    plain = _interpret(tmp_path / "plain", argv)
    scaled = _interpret(tmp_path / "scaled", [*argv, "--time-scale", "120"])
    assert [n for n in scaled.names() if n != "COMMENT"] == [
        n for n in plain.names() if n != "COMMENT"]
    assert [a[0] * 120 for a in scaled.args("DWELL")] == pytest.approx(
        [a[0] for a in plain.args("DWELL")], abs=1e-3 * 120)
    # the cycles at 30 and 90 min stop a turning spindle (0, 60 and 120 min find it at rest)
    assert sum(a[0] for a in scaled.args("DWELL")) == pytest.approx(
        (2 * 3600.0 + 2 * 6.0) / 120, abs=1e-3)
    assert _seconds(header := scaled.header(), r"Dwell in all: ([\d.]+) s") == pytest.approx(
        sum(a[0] for a in scaled.args("DWELL")), abs=1e-3)
    assert "--time-scale 120" in header and "TIME SCALE 120: every dwell is divided" in header
    assert "Not for a real machine" in header and "TIME SCALE" not in plain.header()


def test_the_largest_program_runs_through(tmp_path: Path) -> None:
    """A week with a measuring cycle every minute: 10,081 cycles, each one probed."""
    canon = _interpret(tmp_path, [
        "--hours", "168", "--speeds", "1000,2000,3000,4000", "--probe-every-min", "1",
        "--safe-position", "Z=100", "--probe-at", "Z=10"])
    assert len(canon.args("STRAIGHT_PROBE")) == 168 * 60 + 1
    header = canon.header()
    assert sum(a[0] for a in canon.args("DWELL")) == pytest.approx(
        _seconds(header, r"Dwell in all: ([\d.]+) s"), abs=1e-2)
