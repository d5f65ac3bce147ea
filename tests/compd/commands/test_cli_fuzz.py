"""A fuzzer for the command line: every command with hostile arguments and files.

Each case runs `compd.cli.main(argv)` in-process (a few run as a subprocess:
a reader that closed stdout, a closed stderr, stdout on a full device) and is
accepted only when it ends with one of the sysexits codes of `compd.sysexits`
(health may also say 1, unhealthy), no traceback, and a failure says so in
one line on stderr. Hostile files: empty, garbage bytes, non-UTF-8, NUL
bytes, /dev/zero, a FIFO, a directory, a symbolic link loop, a 2 GiB sparse
file, a missing file; hostile numbers: NaN, ±inf, negative, zero, huge, tiny,
not a number; hostile targets: a directory, a missing directory, "", a FIFO,
/dev/full, a trailing slash, the input itself, a symbolic link loop, a new or
an existing file in /proc (not writable, even by root). Counted in `CASES` (the module
prints the count when collected with -s).
"""

from __future__ import annotations

import os
import random
import subprocess
import sys
from pathlib import Path
from typing import IO

import pytest

from compd.cli import main
from compd.sysexits import EXIT_CODES

#: cases name their files under "@/", replaced by the test's directory when run (the case
#: ids stay the same in every process, as pytest-xdist needs)
ROOT = Path("@")
FILES = ("empty", "garbage", "latin1", "nul", "devzero", "fifo", "dir", "loop", "huge",
         "missing", "bom_only", "toml_junk", "latin1_config")
NUMBERS = ("nan", "inf", "-inf", "-1", "0", "-0.0", "1e308", "1e-9", "1e9", "1e999", "abc",
           "", "0x10")
TARGETS = ("dir", "missing_dir", "empty_name", "fifo", "dev_full", "slash", "loop", "proc_new",
           "proc_file")


def _file(name: str) -> str:
    return "/dev/zero" if name == "devzero" else str(ROOT / name)


def _target(name: str) -> str:
    return {"dir": str(ROOT / "dir"), "missing_dir": str(ROOT / "nodir" / "out.x"),
            "empty_name": "", "fifo": str(ROOT / "fifo"), "dev_full": "/dev/full",
            "slash": str(ROOT / "new") + "/", "input": str(ROOT / "rec.csv"),
            "loop": str(ROOT / "loop"), "proc_new": "/proc/compd-fuzz.png",
            "proc_file": "/proc/version"}[name]


def _make_files(root: Path) -> None:
    rng = random.Random(10)
    (root / "empty").write_bytes(b"")
    (root / "garbage").write_bytes(bytes(rng.randrange(256) for _ in range(4096)))
    (root / "latin1").write_bytes("[model]\nname = \"ré\"\ntime_s,x\n1,2\n".encode("latin-1"))
    (root / "nul").write_bytes(b"time_s,dz_um\n\x00\x00,1\n" * 3)
    (root / "bom_only").write_bytes(b"\xef\xbb\xbf")
    (root / "latin1_config").write_bytes('[machine]\nname = "Süd"\n[controller]\n'.encode(
        "latin-1"))
    (root / "toml_junk").write_text("[model\nperiod_s = = 1\n[[terms]]\n", encoding="utf-8")
    if not (root / "fifo").exists():
        os.mkfifo(root / "fifo")
    (root / "dir").mkdir(exist_ok=True)
    if not os.path.lexists(root / "loop"):
        (root / "loop").symlink_to(root / "loop2")
        (root / "loop2").symlink_to(root / "loop")
    with (root / "huge").open("wb") as f:
        f.truncate(2 << 30)
    lines = [f"{k},{25 + k / 100:.2f},{20 + (k % 7) / 10:.1f},{k / 10:.3f}" for k in range(400)]
    (root / "rec.csv").write_text("time_s,bearing,ambient,dz_um\n" + "\n".join(lines) + "\n",
                                  encoding="utf-8")
    (root / "flat.csv").write_text("time_s,bearing,ambient,dz_um\n" + "\n".join(
        f"{k},25.0,20.0,1.0" for k in range(50)) + "\n", encoding="utf-8")


def _cases() -> list[list[str]]:
    rec = str(ROOT / "rec.csv")
    fit = ["fit", rec, "--column", "dz_um", "--term", "bearing"]
    out: list[list[str]] = [[], ["bogus"], ["check"], ["fit"], ["replay", "sp2"],
                            ["sim", "--record"], ["step", "--plot"], ["check", "sp2", "--nope"],
                            ["replay", "sp2", str(ROOT / "flat.csv"), "--column", "dz_um"],
                            ["replay", "sp2", rec, "--column", "no_such_column"],
                            ["fit", rec, "--column", "dz_um", "--term", "+-"],
                            ["fit", rec, "--column", "dz_um", "--term", "x", "--orders", "9-1"],
                            ["fit", rec, "--column", "dz_um", "--term", "bearing", "--fixed",
                             _file("garbage") + ":t"],
                            ["sim", "--protocol", "modbus", "--record", str(ROOT / "r.csv")],
                            ["sim", "--drive", "nothing://x", "--map", rec]]
    for f in FILES:
        p = _file(f)
        out += [["check", p], ["check", p, "--json"], ["step", p], ["run", p],
                ["replay", "sp2", p, "--column", "dz_um"], ["replay", p, rec, "--column", "dz_um"],
                ["fit", p, "--column", "dz_um", "--term", "bearing"],
                [*fit, "--validation-record", p], [*fit, "--fixed", f"{p}:spindle"],
                ["sim", "--drive", "modbus://127.0.0.1:1", "--map", p],
                ["health", "--state-dir", p, "--max-age-s", "1"],
                ["export", p], ["export", p, "-o", str(ROOT / "x.parquet")]]
    for n in NUMBERS:
        out += [["step", "sp2", "--hours", n], [*fit, "--validation", n],
                [*fit, "--max-time-constant-days", n],
                *([["sim", "--port", n, "--protocol", "modbus"]] if n != "0" else []),
                ["demo", "--hours", n, "--plot", _target("missing_dir")],
                ["demo", "--seconds", n, "--plot", _target("missing_dir")],
                ["health", "--state-dir", str(ROOT / "dir"), "--max-age-s", n],
                ["health", "--state-dir", str(ROOT / "dir"), "--timeout-s", n],
                ["status", "--url", "http://127.0.0.1:1/", "--timeout-s", n]]
    for url in ("", "x", "ftp://127.0.0.1/", "http://", "http://127.0.0.1:99999/",
                "http://[::1/", "http://127.0.0.1:1/status.json", "file:///etc/passwd"):
        out.append(["status", "--url", url])
        for opt in ("--period-s", "--hours", "--probe-noise-um", "--speedup"):
            out.append(["sim", "--record", str(ROOT / "nodir" / "r.csv"), opt, n])
        for opt in ("--duration-h", "--print-every-s"):
            out.append(["sim", "--drive", "modbus://127.0.0.1:1", "--map", _file("missing"),
                        opt, n])
    plan = ["plan", "--hours", "8", "--speeds", "1000,2000", "--dialect", "linuxcnc"]
    for n in NUMBERS:
        out += [["plan", "--hours", n, "--speeds", "1000", "--dialect", "fanuc", "-o",
                 _target("missing_dir")],
                [*plan, "--rest-h", n, "-o", _target("missing_dir")],
                [*plan, "--probe-every-min", n, "--safe-position", "Z=100", "--probe-at",
                 "Z=10", "-o", _target("missing_dir")],
                [*plan, "--safe-position", f"Z={n}", "-o", _target("missing_dir")],
                ["plan", "--hours", "8", "--speeds", f"1000,{n}", "--dialect", "sinumerik",
                 "-o", _target("missing_dir")]]
    for t in ("input", "fifo", "dir"):  # a model or figure over the command's own input
        out += [[*fit, "-o", _target(t), "--force"], [*fit, "--fixed", "sp2:spindle", "-o", rec],
                ["replay", "sp2", rec, "--column", "dz_um", "--plot", rec, "--force"]]
    for bad in ("out.csv", "out", "out.png.txt"):  # not a figure format
        out += [["step", "sp2", "--plot", str(ROOT / bad)],
                ["replay", "sp2", rec, "--column", "dz_um", "--plot", str(ROOT / bad)]]
    for bad_seed in ("-1", "1e3", "x", "99999999999999999999999"):
        out += [["sim", "--record", str(ROOT / "seed.csv"), "--hours", "0.01", "--seed",
                 bad_seed], ["demo", "--seed", bad_seed, "--plot", _target("missing_dir")]]
    for port in ("70000", "-1", "65536"):
        out.append(["sim", "--protocol", "modbus", "--port", port])
    for t in TARGETS:
        p = _target(t)
        out += [[*fit, "-o", p], [*fit, "-o", p, "--force"], ["fit", p, "--column", "x"],
                ["export", rec, "-o", p], ["export", rec, "-o", p, "--format", "parquet"],
                ["sim", "--record", p, "--hours", "0.01"],
                ["sim", "--record", p, "--hours", "0.01", "--force"],
                ["replay", "sp2", rec, "--column", "dz_um", "--plot", p, "--force"],
                ["step", "sp2", "--plot", p, "--force"], ["demo", "--plot", p, "--force"],
                ["sim", "--drive", "modbus://127.0.0.1:1", "--record", p, "--force"],
                [*plan, "-o", p], [*plan, "-o", p, "--force"]]
    return out


CASES = _cases()
print(f"\ncompd CLI fuzzer: {len(CASES)} in-process cases + {3} subprocess cases")


@pytest.fixture(scope="module")
def root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("fuzz")
    _make_files(path)
    return path


def _real(argv: list[str], root: Path) -> list[str]:
    return [a.replace("@/", f"{root}/", 1) if a.startswith("@/") else a for a in argv]


def _check(rc: object, err: str, argv: list[str]) -> None:
    allowed = EXIT_CODES | ({1} if argv[:1] == ["health"] else set())
    assert rc in allowed, (argv, rc, err)
    assert "Traceback" not in err, (argv, err)
    if rc not in (0, 1):
        assert err.strip() and "\n" not in err.strip(), (argv, err)


@pytest.mark.parametrize("argv", CASES, ids=[" ".join(c)[:90] or "(none)" for c in CASES])
def test_hostile_command_line(argv: list[str], root: Path,
                              capsys: pytest.CaptureFixture[str]) -> None:
    try:
        rc: object = main(_real(argv, root))
    except SystemExit as exc:  # the parser's refusals (and --help)
        rc = exc.code
    err = capsys.readouterr().err
    _check(rc, err, argv)
    assert not (root / "new").exists()
    assert (root / "rec.csv").read_text(encoding="utf-8").startswith("time_s,")  # never hit


def _compd(*argv: str, stdout: int | IO[str]) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "compd", *argv], text=True,
                            stdout=stdout, stderr=subprocess.PIPE)


def test_a_reader_that_goes_away_ends_quietly() -> None:
    """``compd check sp2 | head -0``: no BrokenPipeError traceback."""
    proc = _compd("check", "sp2", stdout=subprocess.PIPE)
    assert proc.stdout is not None
    proc.stdout.close()  # before the command even started to print
    _, err = proc.communicate(timeout=120)
    assert proc.returncode in EXIT_CODES and "Traceback" not in err and "Broken" not in err


def test_stdout_on_a_full_device_is_one_line() -> None:
    with open("/dev/full", "w") as full:
        proc = _compd("check", "sp2", stdout=full)
        _, err = proc.communicate(timeout=120)
    _check(proc.returncode, err, ["check"])
    assert proc.returncode == 74


def test_closed_stderr_still_gives_the_exit_code(root: Path) -> None:
    proc = subprocess.run(["sh", "-c", f'exec "{sys.executable}" -m compd check '
                           f'"{root}/missing" 2>&-'], capture_output=True, text=True,
                          timeout=120, check=False)
    assert proc.returncode == 66 and "Traceback" not in proc.stdout
