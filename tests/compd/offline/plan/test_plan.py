"""`compd plan`: the experiment's design (order, lengths, measuring times), the
recorder settings beside the program (accepted by the daemon's own config
loader), and every hostile argument or target ending in one line and a
sysexits code with nothing written."""

from __future__ import annotations

import os
import tomllib
from pathlib import Path

import pytest

from compd.cli import main
from compd.config.loader import load_config
from compd.config.schema import RecorderSection
from compd.offline.plan.schedule import Measure, PlanError, Spin, design
from compd.sysexits import EX_CANTCREAT, EX_USAGE
from models import tomltext
from tests.configs import write_config

# -- the design -------------------------------------------------------------------------


def test_speeds_rise_rest_fall_rest_each_step_as_long_as_a_rest() -> None:
    exp = design(24.0, [5000, 1250, 2500])
    assert [(s.speed_rpm, s.duration_ms / 3_600_000) for s in exp.steps] == [
        (1250, 3.0), (2500, 3.0), (5000, 3.0), (0, 3.0),
        (5000, 3.0), (2500, 3.0), (1250, 3.0), (0, 3.0)]
    assert [s.entry for s in exp.steps] == [
        "rising from rest", "rising", "rising", "falling to rest",
        "rising from rest", "falling", "falling", "falling to rest"]
    assert exp.warnings == ()


def test_the_rests_given_and_odd_hours_still_sum_exactly() -> None:
    exp = design(0.37, [7, 300, 12000], rest_h=0.01)
    assert exp.duration_ms == 1_332_000
    assert exp.steps[3].duration_ms == 36_000  # the first rest as given
    assert {s.duration_ms for s in exp.steps if s.speed_rpm} == {(1_332_000 - 72_000) // 6}
    assert exp.warnings and "min" in exp.warnings[0]  # steps of 3.5 min: said, not refused


def test_measuring_cycles_at_the_start_every_n_minutes_and_at_the_end() -> None:
    exp = design(2.0, [1000, 2000], probe_every_min=25)
    measures = [a for a in exp.actions if isinstance(a, Measure)]
    assert [m.at_ms / 60_000 for m in measures] == [0, 25, 50, 75, 100, 120]
    assert [m.index for m in measures] == list(range(6))
    assert measures[0].stops_rpm == 0 and measures[-1].stops_rpm == 0  # cold, then at rest
    # a cycle stops a turning spindle; after it the spindle turns again exactly when
    # the schedule has a speed there (at 100 min the rest begins: it stays stopped)
    speed_at = {m.at_ms: next(s.speed_rpm for s in exp.steps
                              if s.start_ms <= m.at_ms < s.start_ms + s.duration_ms)
                for m in measures[:-1]}
    assert [m.stops_rpm for m in measures] == [0, 2000, 0, 2000, 1000, 0]
    for k, action in enumerate(exp.actions[:-1]):
        if isinstance(action, Measure):
            following = exp.actions[k + 1]
            wanted = speed_at[action.at_ms]
            assert isinstance(following, Spin) == (wanted > 0)
            assert not isinstance(following, Spin) or following.speed_rpm == wanted


def test_rests_that_leave_no_time_for_the_steps_are_refused() -> None:
    with pytest.raises(PlanError, match="give more --hours"):
        design(6.0, [1000, 2000, 3000], rest_h=3.0)


# -- the command and its files ----------------------------------------------------------


def _plan(tmp_path: Path, *extra: str, name: str = "warmup.ngc") -> int:
    return main(["plan", "--hours", "24", "--speeds", "1250,2500,5000", "--dialect", "linuxcnc",
                 "-o", f"{tmp_path}/{name}", *extra])  # a trailing slash kept


def test_the_recorder_settings_are_what_the_daemon_loads(tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str]
                                                         ) -> None:
    assert _plan(tmp_path, "--probe-every-min", "10", "--safe-position", "Z=100",
                 "--probe-at", "Z=20") == 0
    out = capsys.readouterr().out
    assert "warmup.ngc" in out and "145 measuring cycles" in out and "axes moved: Z" in out
    fragment = (tmp_path / "warmup.recorder.toml").read_text(encoding="utf-8")
    doc = tomllib.loads(fragment)
    section = RecorderSection.model_validate(doc["recorder"])
    assert section.enabled and section.retention_days == 0
    assert str(section.path) == "warmup.sqlite"
    assert "compd fit warmup.sqlite --column dz_um" in fragment
    # not runnable until [controller] and [channels] are added, and says so first
    assert "NOT YET RUNNABLE" in fragment.splitlines()[3]
    machine = write_config(tmp_path, "modbus://127.0.0.1:5020")
    mdoc = tomllib.loads(machine.read_text(encoding="utf-8"))
    config = tmp_path / "warmup.recorder.toml"
    config.write_text(fragment + "\n" + tomltext.dumps(
        {k: mdoc[k] for k in ("controller", "channels")}), encoding="utf-8")
    loaded = load_config(config)
    assert loaded.recorder_only and not loaded.outputs and not loaded.model_given
    assert loaded.recorder_path == tmp_path / "warmup.sqlite"
    assert loaded.state_dir == tmp_path / "warmup.state"
    assert "time_scale" not in fragment


def test_with_the_machines_config_the_recorder_config_runs_as_it_is(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    machine = write_config(tmp_path, "modbus://127.0.0.1:5020")
    assert _plan(tmp_path, "--config", str(machine)) == 0
    path = tmp_path / "warmup.recorder.toml"
    text = path.read_text(encoding="utf-8")
    assert "NOT YET RUNNABLE" not in text and "compd run warmup.recorder.toml" in text
    loaded = load_config(path)
    mine = load_config(machine)
    assert loaded.recorder_only and not loaded.outputs and not loaded.model_given
    assert loaded.channels == mine.channels
    assert loaded.raw.controller == mine.raw.controller
    assert loaded.raw.machine == mine.raw.machine
    assert loaded.recorder_path == tmp_path / "warmup.sqlite"
    assert main(["check", str(path)]) == 0
    assert "recorder only" in capsys.readouterr().out


def test_a_bad_machine_config_is_refused_naming_the_key_and_nothing_is_written(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    machine = write_config(tmp_path, "modbus://127.0.0.1:5020")
    machine.write_text(machine.read_text(encoding="utf-8").replace(
        "[machine]", "[machine]\nbogus = 1"), encoding="utf-8")
    assert _plan(tmp_path, "--config", str(machine)) == 78
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "machine.bogus" in err[0]
    assert not (tmp_path / "warmup.ngc").exists()
    assert not (tmp_path / "warmup.recorder.toml").exists()


def test_a_name_past_the_basic_plane_gives_valid_toml(tmp_path: Path) -> None:
    """JSON writes U+1F600 as a surrogate pair of escapes, which TOML refuses."""
    assert _plan(tmp_path, name="Wärmegang 😀 𝔊.ngc") == 0
    fragment = (tmp_path / "Wärmegang 😀 𝔊.recorder.toml").read_text(encoding="utf-8")
    assert tomllib.loads(fragment)["recorder"]["path"] == "Wärmegang 😀 𝔊.sqlite"


def test_a_time_scale_is_said_beside_the_recorder_settings(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert _plan(tmp_path, "--time-scale", "120") == 0
    assert "at time scale 120" in capsys.readouterr().out
    fragment = (tmp_path / "warmup.recorder.toml").read_text(encoding="utf-8")
    assert "[machine] time_scale = 120" in fragment
    assert RecorderSection.model_validate(tomllib.loads(fragment)["recorder"]).enabled


def test_an_existing_program_is_replaced_only_with_force(tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str]
                                                         ) -> None:
    target = tmp_path / "warmup.ngc"
    target.write_text("(mine)\n", encoding="ascii")
    assert _plan(tmp_path) == EX_CANTCREAT
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--force" in err
    assert target.read_text(encoding="ascii") == "(mine)\n"
    assert not (tmp_path / "warmup.recorder.toml").exists()
    assert _plan(tmp_path, "--force") == 0
    assert target.read_text(encoding="ascii").startswith("(compd plan")


def test_an_existing_recorder_file_stops_both(tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "warmup.recorder.toml").write_text("[recorder]\n", encoding="utf-8")
    assert _plan(tmp_path) == EX_CANTCREAT
    assert "warmup.recorder.toml" in capsys.readouterr().err
    assert not (tmp_path / "warmup.ngc").exists()


@pytest.mark.parametrize("kind", ["directory", "symlink", "dangling", "slash", "missing_dir"])
def test_hostile_targets(tmp_path: Path, capsys: pytest.CaptureFixture[str], kind: str) -> None:
    name = "warmup.ngc"
    if kind == "directory":
        (tmp_path / name).mkdir()
    elif kind == "symlink":
        (tmp_path / "real.ngc").write_text("x", encoding="ascii")
        os.symlink(tmp_path / "real.ngc", tmp_path / name)
    elif kind == "dangling":
        os.symlink(tmp_path / "nowhere.ngc", tmp_path / name)
    elif kind == "slash":
        name = "newdir/"
    else:
        name = "nodir/warmup.ngc"
    assert _plan(tmp_path, "--force", name=name) == EX_CANTCREAT
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    if kind == "symlink":
        assert (tmp_path / "real.ngc").read_text(encoding="ascii") == "x"


@pytest.mark.parametrize("argv", [
    ["--hours", "0"], ["--hours", "-1"], ["--hours", "nan"], ["--hours", "1e9"],
    ["--hours", "inf"], ["--hours", "abc"], ["--hours", ""],
    ["--speeds", ""], ["--speeds", ","], ["--speeds", "1250,"], ["--speeds", "a,b"],
    ["--speeds", "-100"], ["--speeds", "0"], ["--speeds", "1250,1250"],
    ["--speeds", "1250,1250.0"], ["--speeds", "1250.5"], ["--speeds", "nan"],
    ["--speeds", "1e9"], ["--speeds", ",".join(str(k) for k in range(1, 14))],
    ["--rest-h", "0"], ["--rest-h", "-2"], ["--rest-h", "12"],
    ["--probe-every-min", "0"], ["--probe-every-min", "nan"],
    ["--probe-every-min", "10"],  # no --safe-position: the cycle would move blind
    ["--probe-every-min", "10", "--safe-position", "Z=100"],  # linuxcnc: no --probe-at Z
    ["--safe-position", "X=0,Y=0"], ["--safe-position", "Q=1"], ["--safe-position", "Z"],
    ["--safe-position", "Z=nan"], ["--safe-position", "Z=1,Z=2"],
    ["--safe-position", "Z=1e6"], ["--probe-call", "G65 P9810"],
    ["--dialect", "heidenhain"], ["-o", "bad\nname.ngc"],
    ["--time-scale", "0.5"], ["--time-scale", "0"], ["--time-scale", "nan"],
    ["--time-scale", "1e5"],
    ["--probe-at", "Z=10"],  # without --probe-every-min it would measure nothing
], ids=" ".join)
def test_hostile_arguments_end_in_one_line_and_64(tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str],
                                                  argv: list[str]) -> None:
    base = {"--hours": "24", "--speeds": "1250,2500,5000", "--dialect": "linuxcnc",
            "-o": str(tmp_path / "warmup.ngc")}
    given = dict(zip(argv[::2], argv[1::2], strict=True))
    if given.get("-o", "").startswith("bad"):
        given["-o"] = str(tmp_path / given["-o"])
    full = [x for k, v in (base | given).items() for x in (k, v)]
    with pytest.raises(SystemExit) as exit_info:
        raise SystemExit(main(["plan", *full]))
    err = capsys.readouterr().err
    assert exit_info.value.code == EX_USAGE, err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("dialect", ["fanuc", "sinumerik"])
def test_fanuc_and_sinumerik_need_the_users_measuring_cycle(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], dialect: str) -> None:
    rc = main(["plan", "--hours", "8", "--speeds", "1000", "--dialect", dialect,
               "-o", str(tmp_path / "p.nc"), "--probe-every-min", "30",
               "--safe-position", "Z=100"])
    err = capsys.readouterr().err
    assert rc == EX_USAGE and "--probe-call" in err and err.count("\n") == 1
