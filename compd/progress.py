"""Progress of long work on a terminal: one line redrawn in place on stderr.

`terminal_progress(label, quiet=...)` gives a `Progress` that draws only when
stderr is a terminal and the command was not asked for machine output
(``--json``); otherwise it draws nothing, so logs and pipes stay clean.
"""

from __future__ import annotations

import contextlib
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


class Status:
    """``compd fit: identifying the model … 12 s`` on a terminal: the stage
    of work whose length is not known in advance, with the seconds it has
    taken so far redrawn each second by a daemon thread; `done()` clears it."""

    def __init__(self, label: str, stream: TextIO | None) -> None:
        import threading

        self.label = label
        self.stream = stream
        self.text = ""
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._started = 0.0
        self._thread: threading.Thread | None = None
        if stream is not None:
            self._thread = threading.Thread(target=self._tick, daemon=True,
                                            name="compd-progress")

    def stage(self, text: str) -> None:
        import time

        if self.stream is None:
            return
        with self._lock:
            self.text = text
            self._started = time.monotonic()
            self._draw(0)
        if self._thread is not None and not self._thread.is_alive():
            self._thread.start()

    def _draw(self, seconds: int) -> None:
        assert self.stream is not None
        self.stream.write(f"\r\x1b[K{self.label}: {self.text} … {seconds} s")
        self.stream.flush()

    def _tick(self) -> None:
        import time

        while not self._stop.wait(1.0):
            with self._lock:
                try:
                    self._draw(int(time.monotonic() - self._started))
                except (OSError, ValueError):  # the terminal went away
                    return

    def done(self) -> None:
        self._stop.set()
        if self._thread is not None and self._thread.is_alive():
            self._thread.join()
        if self.stream is not None and self.text:
            with self._lock, contextlib.suppress(OSError, ValueError):
                self.text = ""  # cleared once
                self.stream.write("\r\x1b[K")
                self.stream.flush()


def terminal_status(label: str, *, quiet: bool = False, stream: TextIO | None = None) -> Status:
    """A Status drawing on `stream` (stderr) when it is a terminal and not `quiet`."""
    out = sys.stderr if stream is None else stream
    try:
        tty = out is not None and out.isatty()
    except (ValueError, OSError):
        tty = False
    return Status(label, out if tty and not quiet else None)
