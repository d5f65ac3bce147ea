"""The command-line fuzzer's deep and oversized inputs: hostile inputs that end
a command in a traceback unless handled, each with the exit code it must end
with (and one line on stderr, as `test_cli_fuzz` checks every case).

- TOML arrays and tables nested ~900 levels (RecursionError in tomllib): as a
  config, a model, a model a config names, a fixed term, a drive map;
- a CSV field over the csv module's 128 KiB limit (`_csv.Error`);
- a recorder database whose JSON nests without end;
- `demo --model` with a file that is not TOML, an absurd model, a model the
  simulated machine has no channel for, and a speed-up it cannot keep;
- `fit -o` a name of raw bytes (UnicodeEncodeError writing the model);
- counts that made a command run for minutes (`fit --folds 100000`);
- a narrow output encoding (``PYTHONIOENCODING=ascii``, run as a subprocess).

Counted in `CASES` (printed when collected with -s).
"""

from __future__ import annotations

import os
import re
import sqlite3
import subprocess
import sys
import threading
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

from compd.cli import main
from compd.infiles import load_model
from tests.compd.commands.test_cli_fuzz import _check
from tests.shipped import EXAMPLES, LIBRARY

ROOT = Path(__file__).resolve().parents[3]
DEEP = 900
#: a name of raw bytes, as Python gives it from argv (b"\xfe" -> "\udcfe")
RAW_NAME = os.fsdecode(b"\xfe.toml")

#: (argv, the exit code it must end with); "@/" is the test's directory
CASES: list[tuple[list[str], int]] = []


def _add(code: int, *argvs: list[str]) -> None:
    # fit writes nothing without -o (64 before any work): a case about its inputs names one
    CASES.extend(([*argv, "-o", "@/fit_out.toml"] if argv[0] == "fit" and "-o" not in argv
                  else argv, code) for argv in argvs)


REC = "@/rec.csv"
FIT = ["fit", REC, "--column", "dz_um", "--term", "bearing"]
for deep in ("@/deep_array.toml", "@/deep_table.toml", "@/deep_dotted.toml",
             "@/deep_header.toml", "@/deep_config.toml"):
    _add(65, ["check", deep], ["check", deep, "--json"], ["step", deep],
         ["replay", deep, REC, "--column", "dz_um"], [*FIT, "--fixed", f"{deep}:spindle"],
         ["demo", "--model", deep], ["sim", "--drive", "modbus://127.0.0.1:1", "--map", deep])
    _add(78, ["run", deep, "--once", "--dry-run"])
# brackets 900 deep, but only inside strings and comments: the bundled model, read
_add(0, ["check", "@/deep_strings_ok.toml"], ["step", "@/deep_strings_ok.toml"])
_add(78, ["check", "@/config_deep_model.toml"], ["run", "@/config_deep_model.toml", "--once"])
for field in ("@/bigfield.csv", "@/bigfield_header.csv"):
    _add(65, ["fit", field, "--column", "dz_um", "--term", "bearing"],
         [*FIT, "--validation-record", field], ["replay", "sp2", field, "--column", "dz_um"])
_add(65, ["fit", "@/deep.sqlite", "--column", "dz_um", "--term", "bearing"],
     ["export", "@/deep.sqlite"], ["replay", "sp2", "@/deep.sqlite", "--column", "dz_um"])
_add(65, ["demo", "--model", "@/passwd"], ["demo", "--model", "@/nul.toml"],
     ["demo", "--model", "@/latin1.toml"])
_add(78, ["demo", "--model", "@/absurd.toml"], ["demo", "--model", "@/not_a_model.toml"],
     ["demo", "--model", "@/nochannel.toml", "--protocol", "modbus", "--hours", "0.01",
      "--seconds", "1"])
_add(66, ["demo", "--model", ""], ["demo", "--model", "@/missing.toml"],
     ["demo", "--model", "@/"], ["demo", "--model", "/dev/zero"])
_add(64, ["demo", "--seconds", "1e-300"], ["demo", "--hours", "1000", "--seconds", "0.5"],
     ["demo", "--hours", "1000"])
_add(64, [*FIT, "-o", f"@/{RAW_NAME}"], [*FIT, "-o", f"@/{RAW_NAME}", "--force"],
     ["sim", "--record", f"@/{RAW_NAME}", "--hours", "0.01"],
     ["step", "sp2", "--plot", "@/" + os.fsdecode(b"\xff.png")],
     ["export", "@/deep.sqlite", "-o", f"@/{RAW_NAME}"])
for folds in ("100000", "0", "1", "-1", "21", "x", "1e3", "nan", ""):
    _add(64, [*FIT, "--folds", folds])
_add(64, ["fit", "@/flat.csv", "--column", "dz_um", "--term", "bearing", "--folds", "5"])
for terms in ("0", "-1", "13", "100000", "x"):
    _add(64, [*FIT, "--candidates", "*", "--max-terms", terms])
_add(0, [*FIT, "--folds", "20", "-o", "@/folds20.toml"],
     ["fit", REC, "--column", "dz_um", "--candidates", "*", "-o", "@/candidates.toml"],
     ["fit", REC, "--column", "dz_um", "--candidates", "*", "--folds", "3", "-o",
      "@/candidates3.toml"],
     ["fit", "@/flat_rise.csv", "--column", "dz_um", "--term", "bearing", "--folds", "4",
      "-o", "@/folds4.toml"])

# found by running every command with hostile inputs (this round's search):
# 3,000 coefficients (12 KiB) kept `check` computing poles for minutes; 65 terms
_add(78, ["check", "@/long_b.toml"], ["check", "@/many_terms.toml"],
     ["demo", "--model", "@/long_b.toml"])
_add(65, ["step", "@/long_b.toml"], ["replay", "@/long_b.toml", REC, "--column", "dz_um"])
# a record sampled every 1e-300 s (ValueError in the identification) or 1e300 s
_add(65, ["fit", "@/tiny_period.csv", "--column", "dz_um", "--term", "bearing"],
     ["fit", "@/huge_period.csv", "--column", "dz_um", "--term", "bearing"],
     ["replay", "sp2", "@/tiny_period.csv", "--column", "dz_um"])
# a probe more often than the record's rows (numpy "Maximum allowed size exceeded")
_add(64, ["replay", "sp2", REC, "--column", "dz_um", "--probe-every-min", "1e-308"],
     ["replay", "sp2", REC, "--column", "dz_um", "--probe-every-min", "0.005"])
# counts that grow the identification without bound: 200 candidate columns or 60 terms
# took minutes
_add(64, ["fit", "@/wide.csv", "--column", "dz_um", "--candidates", "c*"],
     ["fit", "@/wide.csv", "--column", "dz_um", *(a for i in range(17) for a in
                                                 ("--term", f"c{i}"))])
# a column named bearing_µ chosen by --candidates: the model was written with a bare
# key TOML does not allow, and fit failed reading back its own file (65)
_add(0, ["fit", "@/micro.csv", "--column", "dz_um", "--candidates", "b*", "-o",
         "@/micro.toml"])
# a recorder row whose wall time is 1e308 s (OverflowError formatting the date)
_add(0, ["export", "@/far_future.sqlite"])

print(f"\ncompd CLI fuzzer, deep and oversized inputs: {len(CASES)} in-process cases"
      " + 3 subprocess cases")


def _deep_files(root: Path) -> None:
    arr = "[" * DEEP + "]" * DEEP
    (root / "deep_array.toml").write_text(f"a = {arr}\n", encoding="utf-8")
    (root / "deep_table.toml").write_text("a = " + "{b = " * DEEP + "1" + "}" * DEEP + "\n",
                                          encoding="utf-8")
    (root / "deep_dotted.toml").write_text("a." * DEEP + "b = 1\n", encoding="utf-8")
    (root / "deep_header.toml").write_text("[" + ".".join(["t"] * DEEP) + "]\nx = 1\n",
                                           encoding="utf-8")
    config = (EXAMPLES / "modbus.toml").read_text(encoding="utf-8")
    (root / "deep_config.toml").write_text(
        config.replace("[machine]\n", f"[machine]\nnote = {arr}\n", 1), encoding="utf-8")
    (root / "config_deep_model.toml").write_text(
        re.sub(r'(?m)^file = ".*$', 'file = "deep_array.toml"', config, count=1), encoding="utf-8")
    sp2 = (LIBRARY / "sp2.toml").read_text(encoding="utf-8")
    (root / "deep_strings_ok.toml").write_text(
        f"# {arr}\n" + re.sub(r'(?m)^description = .*$', f'description = "{arr}"', sp2, count=1)
        + f"\n# {arr}\n", encoding="utf-8")


def _model(inputs: str, a: str, b: str) -> str:
    return (f'[model]\nname = "m"\nperiod_s = 1.0\n[[terms]]\nname = "spindle"\n'
            f"inputs = {{ {inputs} }}\na = [{a}]\nb = [{b}]\n")


def _recorder(path: Path, channels: str, wall_s: float = 0.0) -> None:
    conn = sqlite3.connect(path)
    conn.execute("CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT)")
    conn.execute("INSERT INTO meta VALUES ('channels', ?)", (channels,))
    conn.execute("CREATE TABLE samples (seq, cycle, mono_s, wall_s, offset_um, model_um, state,"
                 " valid, channels, validity, contributions)")
    conn.executemany("INSERT INTO samples VALUES (?,?,?,?,?,?,?,?,?,?,?)",
                     [(i, i, float(i), wall_s + i, 0.0, 0.0, 0, 1, "{}", "{}", "{}")
                      for i in range(5)])
    conn.commit()
    conn.close()


@pytest.fixture(scope="module")
def root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("fuzz3")
    _deep_files(path)
    rows = [f"{k},{25 + k / 100:.2f},{20 + (k % 7) / 10:.1f},{k / 10:.3f}" for k in range(400)]
    (path / "rec.csv").write_text("time_s,bearing,ambient,dz_um\n" + "\n".join(rows) + "\n",
                                  encoding="utf-8")
    (path / "flat.csv").write_text("time_s,bearing,ambient,dz_um\n" + "".join(
        f"{k},{25 + k / 10:.1f},20.0,{k / 5:.2f}\n" for k in range(50)), encoding="utf-8")
    (path / "flat_rise.csv").write_text((path / "flat.csv").read_text(encoding="utf-8"),
                                        encoding="utf-8")
    big = "a" * (129 * 1024)
    (path / "bigfield.csv").write_text(
        "time_s,bearing,dz_um\n0,20,0\n1,20,0\n2," + big + ",0\n3,20,0\n", encoding="utf-8")
    (path / "bigfield_header.csv").write_text(f"time_s,{big}\n0,1\n", encoding="utf-8")
    _recorder(path / "deep.sqlite", "[" * 100_000 + "]" * 100_000)
    _recorder(path / "far_future.sqlite", "[]", wall_s=1e308)
    (path / "long_b.toml").write_text(
        _model("bearing = 1.0", '"0.5"', ", ".join(['"1"', *['"0"'] * 2998, '"-0.5"'])),
        encoding="utf-8")
    term = ('[[terms]]\nname = "t{}"\ninputs = {{ bearing = 1.0 }}\na = ["0.01"]\n'
            'b = ["1", "-0.5"]\n')
    (path / "many_terms.toml").write_text(
        '[model]\nname = "m"\nperiod_s = 1.0\n' + "".join(term.format(i) for i in range(65)),
        encoding="utf-8")
    for name, dt in (("tiny_period.csv", 1e-300), ("huge_period.csv", 1e300)):
        (path / name).write_text("time_s,bearing,ambient,dz_um\n" + "".join(
            f"{k * dt!r},{20 + k / 10},20,{k / 10}\n" for k in range(50)), encoding="utf-8")
    (path / "wide.csv").write_text("time_s," + ",".join(f"c{i}" for i in range(40)) + ",dz_um\n"
                                   + "".join(f"{k}," + ",".join(f"{20 + (i * k) % 7}" for i in
                                                                range(40)) + f",{k % 5}\n"
                                             for k in range(50)), encoding="utf-8")
    (path / "micro.csv").write_text((path / "rec.csv").read_text(encoding="utf-8").replace(
        "bearing", "bearing_µ", 1), encoding="utf-8")
    (path / "passwd").write_text("root:x:0:0:root:/root:/bin/bash\n", encoding="utf-8")
    (path / "nul.toml").write_bytes(b"[model]\x00\n")
    (path / "latin1.toml").write_bytes('[model]\nname = "Süd"\n'.encode("latin-1"))
    (path / "absurd.toml").write_text(_model("bearing = 1.0", '"1e308", "-0.9e308"',
                                             '"1", "-0.5"'), encoding="utf-8")
    (path / "nochannel.toml").write_text(_model("nosuch = 1.0", '"0.1"', '"1", "-0.5"'),
                                         encoding="utf-8")
    (path / "not_a_model.toml").write_text('title = "x"\n', encoding="utf-8")
    return path


def _real(argv: list[str], root: Path) -> list[str]:
    return [f"{root}/{a[2:]}" if a.startswith("@/") else a for a in argv]


@pytest.mark.parametrize(("argv", "code"), CASES,
                         ids=[ascii(" ".join(c))[1:-1][:90] for c, _ in CASES])
def test_hostile_deep_or_oversized_input(argv: list[str], code: int, root: Path,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    try:
        rc: object = main(_real(argv, root))
    except SystemExit as exc:  # the parser's refusals
        rc = exc.code
    err = capsys.readouterr().err
    _check(rc, err, argv)
    assert rc == code, (argv, rc, err)
    assert not (root / RAW_NAME).exists()


def test_raw_byte_arguments_are_kept_escaped_in_the_model(root: Path,
                                                          capsys: pytest.CaptureFixture[str],
                                                          ) -> None:
    raw = os.fsdecode(b"\xfe")
    out = root / "raw_name.toml"
    assert main([*_real(FIT, root), "--name", raw, "-o", str(out), "--force"]) == 0
    assert load_model(out).name == "\\udcfe"  # written as text, read back
    assert "Traceback" not in capsys.readouterr().err


def _compd(*argv: str, encoding: str) -> subprocess.CompletedProcess[bytes]:
    env = {**os.environ, "PYTHONIOENCODING": encoding}
    return subprocess.run([sys.executable, "-m", "compd", *argv], cwd=ROOT, env=env,
                          capture_output=True, timeout=120, check=False)


@pytest.mark.parametrize(("argv", "code"), [
    (["check", "sp2"], 0), (["check", str(EXAMPLES / "modbus.toml")], 0),
    (["check", "tests/nonexistent/µ°±.toml"], 66)])
def test_a_narrow_output_encoding_never_ends_a_command(argv: list[str], code: int) -> None:
    done = _compd(*argv, encoding="ascii")
    assert done.returncode == code, done.stderr
    assert b"Traceback" not in done.stderr and b"UnicodeEncodeError" not in done.stderr
    text = done.stdout + done.stderr
    assert text.isascii()
    if code == 0:
        assert b"\\xb5m" in done.stdout  # µm, escaped
    else:
        assert len(done.stderr.strip().splitlines()) == 1


#: status pages a hostile or broken server may send (`compd status --url`)
PAGES = {
    "nested": b"[" * 100_000 + b"]" * 100_000,
    "nested_object": b'{"machines": ' + b'{"a": ' * 50_000 + b"1" + b"}" * 50_000 + b"}",
    "huge_ints": b'{"machines": [{"state": "on", "age_s": 1' + b"0" * 400 + b', "period_s": 1,'
                 b' "offset_um": -1' + b"0" * 400 + b', "limit_um": 1' + b"0" * 400 + b"}]}",
    "wrong_types": b'{"state": "on", "machine": {"a": 1}, "why": [1], "channels": 5, '
                   b'"limit_um": true, "age_s": "x", "offset_um": NaN}',
    "channels_text": b'{"state": "on", "channels": "abc"}',
    "latin1": '{"state": "Süd"}'.encode("latin-1"),
}


@pytest.fixture(scope="module")
def page_server() -> Iterator[str]:
    class Pages(BaseHTTPRequestHandler):
        def do_GET(self) -> None:
            body = PAGES[self.path.strip("/").removesuffix("/status.json")]
            self.send_response(200)
            self.send_header("Content-Type", "application/json")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args: object) -> None:
            pass

    server = ThreadingHTTPServer(("127.0.0.1", 0), Pages)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()
        thread.join()


@pytest.mark.parametrize("page", sorted(PAGES))
def test_a_hostile_status_page_is_one_line(page: str, page_server: str,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    for extra in ([], ["--json"]):
        rc = main(["status", "--url", f"{page_server}/{page}/status.json", *extra])
        err = capsys.readouterr().err
        assert rc in (0, 1, 65), (page, rc, err)  # on, not all on, not a status page
        assert "Traceback" not in err
        assert rc in (0, 1) or len(err.strip().splitlines()) == 1, err
    if page.startswith("nested"):
        assert rc == 65
