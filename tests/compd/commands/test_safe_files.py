"""Files a command writes or reads (and the bad-input list).

Outputs are checked before the work starts and written atomically: never over
an input (also through a symbolic or hard link), never over an existing file
without --force, never to a directory, device or FIFO. Inputs must be regular
files of a sane size in UTF-8; a CSV record is streamed into float64 columns.
"""

from __future__ import annotations

import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from compd.cli import main
from compd.outfiles import OutputError, write_atomically
from tests.compd.offline.records_gen import make_record


def _rc(argv: list[str]) -> int:
    try:
        return main(argv)
    except SystemExit as exc:  # the parser's refusals
        return int(str(exc.code))


@pytest.fixture(scope="module")
def record(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("rec") / "calib.csv"
    make_record(path, "sp2", hours=1.0, seed=3)
    return path


def _fit(record: Path, *extra: str) -> list[str]:
    return ["fit", str(record), "--column", "dz_um", "--term", "spindle=bearing",
            "--orders", "1-1", *extra]


def test_fit_never_overwrites_its_own_record(record: Path, tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    before = record.read_bytes()
    assert _rc(_fit(record, "-o", str(record))) == 73
    assert _rc(_fit(record, "-o", str(record), "--force")) == 73  # not even with --force
    link = tmp_path / "link.csv"
    link.symlink_to(record)
    hard = tmp_path / "hard.csv"
    os.link(record, hard)
    assert _rc(_fit(record, "-o", str(hard), "--force")) == 73  # same inode
    assert _rc(_fit(record, "-o", str(link), "--force")) == 73  # a link is not a target
    assert record.read_bytes() == before
    err = capsys.readouterr().err
    assert "is the input" in err and "Traceback" not in err


def test_fit_refuses_an_existing_model_file_without_force(record: Path, tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]
                                                          ) -> None:
    out = tmp_path / "m.toml"
    out.write_text("# an older model\n", encoding="utf-8")
    assert _rc(_fit(record, "-o", str(out))) == 73
    assert out.read_text(encoding="utf-8") == "# an older model\n"
    assert "--force" in capsys.readouterr().err
    assert _rc(_fit(record, "-o", str(out), "--force")) == 0
    assert "[[terms]]" in out.read_text(encoding="utf-8")
    assert [p.name for p in tmp_path.iterdir()] == ["m.toml"]  # no temporary file left


@pytest.mark.parametrize("target", ["dir", "fifo", "missing/m.toml", "dev"])
def test_fit_refuses_non_regular_or_uncreatable_targets(record: Path, tmp_path: Path,
                                                        target: str) -> None:
    (tmp_path / "dir").mkdir()
    os.mkfifo(tmp_path / "fifo")
    path = "/dev/full" if target == "dev" else str(tmp_path / target)
    assert _rc(_fit(record, "-o", path, "--force")) == 73
    assert stat.S_ISCHR(os.stat("/dev/full").st_mode)
    assert stat.S_ISFIFO(os.stat(tmp_path / "fifo").st_mode)


@pytest.mark.parametrize("target", ["", "dir", "missing/r.csv", "fifo", "dir/"])
def test_sim_record_refuses_bad_targets(tmp_path: Path, target: str,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "dir").mkdir()
    os.mkfifo(tmp_path / "fifo")
    path = target and str(tmp_path / target) + ("/" if target.endswith("/") else "")
    assert _rc(["sim", "--record", path, "--hours", "0.01", "--force"]) == 73
    assert stat.S_ISFIFO(os.stat(tmp_path / "fifo").st_mode)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dir", "fifo"]
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_sim_record_refuses_a_silly_period(tmp_path: Path) -> None:
    assert _rc(["sim", "--record", str(tmp_path / "r.csv"), "--period-s", "1e-9"]) == 64
    assert _rc(["sim", "--record", str(tmp_path / "r.csv"), "--hours", "8000",
                "--period-s", "0.001"]) == 65
    assert not list(tmp_path.iterdir())


def test_sim_drive_record_is_checked_before_the_session(tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]
                                                        ) -> None:
    from drivers.sim.ports import free_tcp_port

    url = f"modbus://127.0.0.1:{free_tcp_port()}"  # nobody listens: it would run on
    assert _rc(["sim", "--drive", url, "--duration-h", "0.01",
                "--record", str(tmp_path / "missing" / "run.csv")]) == 73
    out = capsys.readouterr()
    assert "driving" not in out.out and "does not exist" in out.err


def test_plot_to_a_missing_directory_is_refused_before_the_work(
        tmp_path: Path, record: Path, capsys: pytest.CaptureFixture[str]) -> None:
    png = str(tmp_path / "missing" / "f.png")
    assert _rc(["replay", "sp2", str(record), "--column", "dz_um", "--plot", png]) == 73
    assert _rc(["step", "sp2", "--plot", png]) == 73
    out = capsys.readouterr()
    assert out.out == "" and out.err.count("\n") == 2


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path: Path) -> None:
    target = tmp_path / "model.toml"
    target.write_text("old\n", encoding="utf-8")

    def fill(tmp: Path) -> None:
        with tmp.open("w") as f, open("/dev/full", "w") as full:
            f.write("half")
            full.write("x" * 8192)
            full.flush()  # ENOSPC, as on a full disk

    with pytest.raises(OutputError) as exc:
        write_atomically(target, fill, "model file", force=True)
    assert exc.value.code == 74
    assert target.read_text(encoding="utf-8") == "old\n"
    assert [p.name for p in tmp_path.iterdir()] == ["model.toml"]


@pytest.mark.parametrize("name", ["m" * 251 + ".ngc", "a.b" + "c" * 240 + ".png",
                                  "\U0001f600" * 62 + ".ngc", "x." + "y" * 250])
def test_a_name_at_the_file_systems_limit_is_written(tmp_path: Path, name: str) -> None:
    """The temporary file beside a target whose name is near 255 bytes still fits:
    its name keeps a cut of the target's, and the suffix only when it is short."""
    assert len(name.encode()) <= 255
    seen: list[str] = []

    def fill(tmp: Path) -> None:
        seen.append(tmp.name)
        tmp.write_text("new\n", encoding="utf-8")

    target = write_atomically(tmp_path / name, fill, "program")
    assert target.read_text(encoding="utf-8") == "new\n"
    assert [p.name for p in tmp_path.iterdir()] == [name]
    suffix = Path(name).suffix
    assert seen[0].endswith(".part" + (suffix if len(suffix) <= 16 else ""))


# -- inputs -----------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["devzero", "fifo", "dir", "loop", "bigsparse", "latin1"])
def test_hostile_model_files_end_in_one_line(tmp_path: Path, kind: str,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "m.toml"
    if kind == "devzero":
        path = Path("/dev/zero")
    elif kind == "fifo":
        os.mkfifo(path)
    elif kind == "dir":
        path.mkdir()
    elif kind == "loop":
        path.symlink_to(tmp_path / "m2.toml")
        (tmp_path / "m2.toml").symlink_to(path)
    elif kind == "bigsparse":
        with path.open("wb") as f:
            f.truncate(64 << 20)
    else:
        path.write_bytes('[model]\nname = "caf\xe9"\n'.encode("latin-1"))
    for argv in (["check", str(path)], ["step", str(path)],
                 ["replay", str(path), str(path), "--column", "dz_um"]):
        assert _rc(argv) in (65, 66, 78)
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "Traceback" not in err
        if kind == "latin1":
            assert "UTF-8" in err


def test_hostile_records_end_in_one_line(tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    fifo = tmp_path / "r.csv"
    os.mkfifo(fifo)
    huge = tmp_path / "huge.csv"
    with huge.open("wb") as f:
        f.truncate((1 << 30) + 1)
    bad_db = tmp_path / "bad.db"
    _corrupt_recorder(bad_db)
    for data, code in ((fifo, 66), (huge, 65), (Path("/dev/zero"), 66), (bad_db, 65)):
        assert _rc(["replay", "sp2", str(data), "--column", "dz_um"]) == code
        assert _rc(["fit", str(data), "--column", "dz_um", "--term", "bearing", "-o",
                    str(tmp_path / "out.toml")]) == code
        err = capsys.readouterr().err
        assert err.count("\n") == 2 and "Traceback" not in err, err


def _corrupt_recorder(path: Path) -> None:
    import sqlite3

    from compd.runtime.recorder import Recorder, RecordRow

    with Recorder(path, commit_every=1) as rec:
        for k in range(5):
            rec.record(RecordRow(seq=k, mono_s=float(k), wall_s=1e9 + k, offset_um=None,
                                 model_um=0.0, state="running", valid=True,
                                 channels={"bearing": 20.0, "dz_um": 0.1 * k}))
    conn = sqlite3.connect(path)
    conn.execute("UPDATE samples SET channels = '{not json' WHERE seq = 2")
    conn.commit()
    conn.close()


def test_a_drive_map_that_is_not_utf8_is_refused(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "map.toml"
    bad.write_bytes(b"[driver]\nname = \"\xff\xfe\"\n")
    assert _rc(["sim", "--drive", "modbus://127.0.0.1:1", "--map", str(bad)]) == 65
    assert "UTF-8" in capsys.readouterr().err


def test_a_large_record_is_streamed_not_held_as_text(tmp_path: Path) -> None:
    """Peak memory of `compd replay` grows by a small multiple of the 8 bytes per
    number, not by the ~60 bytes per cell of Python strings and lists."""
    rows = 300_000
    path = tmp_path / "big.csv"
    with path.open("w") as f:
        f.write("time_s,bearing,ambient,dz_um\n")
        f.writelines(f"{k},{25 + (k % 5000) / 1000:.3f},20.0,{(k % 5000) / 100:.3f}\n"
                     for k in range(rows))
    probe = ("import resource, sys\nfrom compd.cli import main\n"
             "rc = main(sys.argv[1:])\n"
             "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)\nsys.exit(rc)\n")
    base = subprocess.run([sys.executable, "-c", probe, "step", "sp2", "--hours", "1"],
                          capture_output=True, text=True, check=True)
    res = subprocess.run([sys.executable, "-c", probe, "replay", "sp2", str(path), "--column",
                          "dz_um"], capture_output=True, text=True, check=True)
    grown_kib = int(res.stdout.split()[-1]) - int(base.stdout.split()[-1])
    numbers_kib = rows * 4 * 8 / 1024
    assert grown_kib < 5 * numbers_kib, (grown_kib, numbers_kib)


def test_a_fifo_input_does_not_hang(tmp_path: Path) -> None:
    fifo = tmp_path / "m.toml"
    os.mkfifo(fifo)
    proc = subprocess.run([sys.executable, "-m", "compd", "check", str(fifo)],
                          capture_output=True, text=True, timeout=120, check=False)  # hung
    assert proc.returncode == 66
    assert "a FIFO" in proc.stderr and proc.stderr.count("\n") == 1


# -- the bad-input list ------------------------------------------------------------


def _model(path: Path, period_s: str, a: str, b: str) -> Path:
    path.write_text(f'[model]\nname = "m"\nperiod_s = {period_s}\n\n[[terms]]\nname = "t"\n'
                    f'inputs = {{ bearing = 1.0 }}\na = {a}\nb = {b}\n', encoding="utf-8")
    return path


def test_step_refuses_absurd_spans(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for hours in ("nan", "inf", "1e9", "-1", "0"):
        assert _rc(["step", "sp2", "--hours", hours]) == 64
    fast = _model(tmp_path / "fast.toml", "1e-9", '["0.5"]', '["1", "-0.5"]')
    rc = _rc(["step", str(fast), "--hours", "1"])
    assert rc in (65, 78)  # refused by the step's sample cap or by the model's period bounds
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 6 and "Traceback" not in "\n".join(err)


def test_fit_validation_and_time_constant_must_be_in_range(record: Path) -> None:
    for v in ("1.5", "0", "-1", "nan", "1"):
        assert _rc(_fit(record, "--validation", v)) == 64
    for d in ("0", "-3", "inf", "nan", "1e308"):
        assert _rc(_fit(record, "--max-time-constant-days", d)) == 64


def test_sim_ports_and_noise(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import socket

    for p in ("70000", "-1", "x"):
        assert _rc(["sim", "--protocol", "modbus", "--port", p]) == 64
    for noise in ("nan", "-1", "inf"):
        assert _rc(["sim", "--record", str(tmp_path / "r.csv"), "--probe-noise-um",
                    noise]) == 64
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = str(busy.getsockname()[1])
        assert _rc(["sim", "--protocol", "modbus", "--port", port]) == 75
    assert "cannot serve on 127.0.0.1:" in capsys.readouterr().err


def test_replay_never_reports_fit_nan(tmp_path: Path, record: Path,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    huge = _model(tmp_path / "huge.toml", "1.0", '["1e308", "1e308"]', '["1", "-0.999"]')
    rc = _rc(["replay", str(huge), str(record), "--column", "dz_um"])
    out = capsys.readouterr()
    assert rc in (65, 78) and "nan" not in out.out
    assert out.err.count("\n") == 1 and "Traceback" not in out.err


def test_check_piped_into_a_reader_that_goes_away(tmp_path: Path) -> None:
    proc = subprocess.run(f'"{sys.executable}" -m compd check sp2 | head -c 10 >/dev/null; '
                          'exit "${PIPESTATUS[0]}"', shell=True, executable="/bin/bash",
                          capture_output=True, text=True, timeout=120, check=False)
    assert "Traceback" not in proc.stderr and "BrokenPipe" not in proc.stderr
    assert proc.returncode in (0, 74)
