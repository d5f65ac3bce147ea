"""Progress is drawn on a terminal only, never with --json or into a pipe."""

from __future__ import annotations

import io

from compd.progress import terminal_progress


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

