"""Progress is drawn on a terminal only, never with --json or into a pipe."""

from __future__ import annotations

import io
from pathlib import Path

import pytest

from compd.cli import main
from compd.progress import terminal_progress, terminal_status


class Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_draws_on_a_terminal_once_per_percent() -> None:
    tty = Tty()
    bar = terminal_progress("machine time", total=8.0, unit="h", stream=tty)
    for k in range(801):
        bar.update(k / 100.0)
    bar.done()
    text = tty.getvalue()
    assert text.count("\r") == 101 and text.endswith("100 %  8 of 8 h\n")
    assert "[###############...............]  50 %  4 of 8 h" in text


def test_no_progress_into_a_pipe_or_with_json() -> None:
    pipe = io.StringIO()
    for bar in (terminal_progress("x", stream=pipe), terminal_progress("x", quiet=True,
                                                                         stream=Tty())):
        assert not bar.active
        bar.update(0.5)
        bar.done()
    assert pipe.getvalue() == ""



def test_a_status_names_each_stage_on_a_terminal_and_clears_the_line() -> None:
    tty = Tty()
    status = terminal_status("compd fit", stream=tty)
    status.stage("identifying the model")
    status.stage("replaying")
    status.done()
    status.done()
    text = tty.getvalue()
    assert "compd fit: identifying the model … 0 s" in text
    assert "compd fit: replaying … 0 s" in text
    assert text.endswith("\r\x1b[K") and text.count("\r\x1b[K") >= 3


def test_fit_draws_no_status_into_a_pipe(tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    rec = tmp_path / "rec.csv"
    rec.write_text("time_s,bearing,dz_um\n" + "".join(
        f"{k},{25 + k / 100:.2f},{k / 10 + (k % 5) / 50:.3f}\n" for k in range(300)),
        encoding="utf-8")
    assert main(["fit", str(rec), "--column", "dz_um", "--term", "bearing", "--orders", "1-1",
                 "-o", str(tmp_path / "m.toml")]) == 0
    captured = capsys.readouterr()
    assert "\r" not in captured.err + captured.out
    assert not terminal_status("compd fit", stream=Tty(), quiet=True).stream
