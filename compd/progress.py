"""Progress of long work on a terminal: one line redrawn in place on stderr.

`terminal_progress(label, quiet=...)` gives a `Progress` that draws only when
stderr is a terminal and the command was not asked for machine output
(``--json``); otherwise it draws nothing, so logs and pipes stay clean.
"""

from __future__ import annotations

import sys
from typing import TextIO

WIDTH = 30


class Progress:
    """``label [#########.........]  32 %  2.6 of 8 h`` redrawn at most once per
    whole percent; `done()` ends the line."""

    def __init__(self, label: str, stream: TextIO | None, *, total: float = 1.0,
                 unit: str = "") -> None:
        self.label = label
        self.stream = stream
        self.total = total
        self.unit = unit
        self.percent = -1

    @property
    def active(self) -> bool:
        return self.stream is not None

    def update(self, done: float) -> None:
        if self.stream is None or self.total <= 0.0:
            return
        fraction = min(max(done / self.total, 0.0), 1.0)
        percent = int(fraction * 100.0)
        if percent == self.percent:
            return
        self.percent = percent
        bar = "#" * round(fraction * WIDTH) + "." * (WIDTH - round(fraction * WIDTH))
        of = f"  {done:.3g} of {self.total:g} {self.unit}".rstrip() if self.unit else ""
        self.stream.write(f"\r{self.label} [{bar}] {percent:3d} %{of}")
        self.stream.flush()

    def done(self) -> None:
        if self.stream is not None and self.percent >= 0:
            self.stream.write("\n")
            self.stream.flush()
            self.percent = -1


def terminal_progress(label: str, *, quiet: bool = False, total: float = 1.0, unit: str = "",
                      stream: TextIO | None = None) -> Progress:
    """A Progress drawing on `stream` (stderr) when it is a terminal and not `quiet`."""
    out = sys.stderr if stream is None else stream
    try:
        tty = out is not None and out.isatty()
    except (ValueError, OSError):  # closed
        tty = False
    return Progress(label, out if tty and not quiet else None, total=total, unit=unit)
