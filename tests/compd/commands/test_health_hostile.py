"""`compd health` given hostile input: a URL whose port is not
a number, a checkpoint nested thousands of levels deep. One line and a sysexits
code, never a traceback."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from compd.cli import main
from compd.runtime.checkpoint import CheckpointError, load_checkpoint

ROOT = Path(__file__).resolve().parents[3]


@pytest.mark.parametrize(("url", "why"), [
    ("http://127.0.0.1:abc/metrics", "Port could not be cast"),
    ("http://127.0.0.1:99999/metrics", "out of range"),
    ("http://127.0.0.1:0/metrics", "port 0"),
    ("ftp://127.0.0.1:9105/metrics", "scheme 'ftp'"),
    ("http:///metrics", "no host"),
    ("http://127.0.0.1:9105/me trics", "space or control"),
])
def test_a_url_that_cannot_be_an_endpoint_is_a_usage_error(
        url: str, why: str, capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["health", "--url", url])
    out = capsys.readouterr()
    assert rc == 64 and out.out == ""
    assert out.err.count("\n") == 1 and "--url" in out.err and why in out.err


def test_a_bad_port_ends_in_one_line_not_a_traceback() -> None:
    """The issue's case as a user runs it (it ended in http.client.InvalidURL)."""
    proc = subprocess.run([sys.executable, "-m", "compd", "health", "--url",
                           "http://127.0.0.1:abc/metrics"], capture_output=True, text=True,
                          check=False, timeout=60, cwd=ROOT)
    assert proc.returncode == 64, proc.stderr
    assert "Traceback" not in proc.stderr and proc.stderr.count("\n") == 1


def test_credentials_in_a_bad_url_are_not_echoed(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["health", "--url", "http://user:SECRETPW@127.0.0.1:abc/metrics"]) == 64
    err = capsys.readouterr().err
    assert "SECRETPW" not in err and "--url" in err


def _deep(path: Path, levels: int = 100_000) -> None:
    path.write_text("[" * levels + "]" * levels)


def test_a_deeply_nested_checkpoint_is_unhealthy_not_a_traceback(tmp_path: Path) -> None:
    state = tmp_path / "state"
    state.mkdir(mode=0o700)
    _deep(state / "checkpoint.json")
    proc = subprocess.run([sys.executable, "-m", "compd", "health", "--state-dir", str(state)],
                          capture_output=True, text=True, check=False, timeout=60, cwd=ROOT)
    assert proc.returncode == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    assert proc.stdout == f"unhealthy: state dir {state}: checkpoint unreadable " \
                          "(arrays and tables nested more than 320 levels deep; at most 32 " \
                          "are accepted)\n"


def test_a_deeply_nested_checkpoint_is_refused_on_load(tmp_path: Path) -> None:
    path = tmp_path / "checkpoint.json"
    _deep(path)
    with pytest.raises(CheckpointError, match=r"nested .* deep"):
        load_checkpoint(path)
