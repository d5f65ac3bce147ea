"""The daemon's voice: what the cycle and its sinks report, to the log and to
the status page's alarm list.

- `events`: the cycle's `compd.core.events.Event`s, each logged at the level
  its name carries; warnings and errors also become alarms on the page;
- ``write_failed`` and ``probe_refused`` can repeat every cycle (an outage, a
  stuck probe counter): the first is logged, then a summary a minute, then
  ``<name>_recovered`` (`compd.runtime.repeats.RepeatLimiter`);
- `cycle_error`: an exception where none is expected, per stage of the cycle
  (``step``, ``record``, ``telemetry``, ...), likewise once then summaries;
- `guard`: runs one sink's step so that its exception is such a
  ``cycle_error`` and never stops the cycle (the offset is written already).

`log` is replaceable (a test stands its own logger in before the run). Times
come from the injected monotonic clock (`compd.runtime.clock`).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterable, Mapping
from typing import Any

from compd.core.events import Event, EventName, Level
from compd.faces.status import StatusBoard
from compd.runtime.clock import Clock
from compd.runtime.repeats import RepeatLimiter

__all__ = ["Journal"]

_LIMITED = {EventName.WRITE_FAILED, EventName.PROBE_REFUSED}


class Journal:
    def __init__(self, log: Any, board: StatusBoard, clock: Clock) -> None:
        self.log = log
        self.board = board
        self._mono = clock.mono
        self._wall = clock.wall
        self._limiters = {name: RepeatLimiter(name.value) for name in _LIMITED}
        #: exceptions where none is expected, per stage of the cycle
        self._cycle_errors: dict[str, RepeatLimiter] = {}

    def events(self, events: Iterable[Event], *, alarms: bool = True) -> None:
        for ev in events:
            name = EventName(ev.name)
            limiter = self._limiters.get(name)
            if limiter is not None:  # once, then a summary a minute
                self.repeat(limiter.failed(self._mono(), ev.plain()))
                continue
            if name is EventName.PROBE_ACCEPTED:  # ends a run of refusals
                self.repeat(self._limiters[EventName.PROBE_REFUSED].succeeded(self._mono()))
            fields = ev.plain()
            getattr(self.log, name.level)(name.value, **fields)
            if alarms and name.level is not Level.INFO:
                self.alarm(name.value, name.level.value, fields)

    def alarm(self, name: str, level: str, fields: Mapping[str, Any]) -> None:
        """A warning or error on the status page, stamped with the daemon's wall clock."""
        self.board.alarm(name, level, fields, wall_s=self._wall())

    def write_ok(self) -> None:
        """A write went through: ends a run of ``write_failed``."""
        self.repeat(self._limiters[EventName.WRITE_FAILED].succeeded(self._mono()))

    def repeat(self, line: tuple[str, dict[str, Any]] | None) -> None:
        """One line of a `RepeatLimiter` (the first, a summary, or ``_recovered``)."""
        if line is not None:
            name, fields = line
            level = "info" if name.endswith("_recovered") else "warning"
            getattr(self.log, level)(name, **fields)
            if level == "warning":
                self.alarm(name, level, fields)

    def guard(self, stage: str, fn: Callable[..., object], *args: Any) -> None:
        """`fn(*args)`; an exception is a ``cycle_error`` of `stage`, never raised."""
        try:
            fn(*args)
        except Exception as exc:
            self.cycle_error(stage, exc)
        else:
            limiter = self._cycle_errors.get(stage)
            if limiter is not None:
                self.repeat(limiter.succeeded(self._mono()))

    def cycle_error(self, stage: str, exc: Exception) -> None:
        """An exception where none is expected: one line with it (then a summary a
        minute while it repeats), an alarm on the status page."""
        limiter = self._cycle_errors.setdefault(stage, RepeatLimiter("cycle_error"))
        line = limiter.failed(self._mono(), {"stage": stage,
                                             "error": f"{type(exc).__name__}: {exc}"})
        if line is not None:
            name, fields = line
            self.log.error(name, **fields, exc_info=exc if name == "cycle_error" else None)
            with contextlib.suppress(Exception):
                self.alarm(name, "error", fields)
