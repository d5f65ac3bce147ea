"""Log a repeating failure once, then as a summary: an outage of an hour at
1 Hz wrote 3,600 ``write_failed`` lines (and the library's own dumps), which
buries the one line an operator needs.

`RepeatLimiter` passes the first event of a run of failures, holds back the
rest (counting them), lets one ``<name>_summary`` line through every
`summary_every_s` seconds (how many, the last error), and turns the first
success after a run into a ``<name>_recovered`` line with the count and the
duration. It takes the time as an argument (pure; the shell passes its
monotonic clock).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

__all__ = ["RepeatLimiter"]


@dataclass
class RepeatLimiter:
    """Throttle one event name; see the module docstring."""

    name: str
    summary_every_s: float = 60.0
    failures: int = 0
    _held: int = 0
    _since_s: float = 0.0
    _summary_s: float = 0.0
    _last: dict[str, Any] = field(default_factory=dict)

    def failed(self, now_s: float, fields: dict[str, Any]) -> tuple[str, dict[str, Any]] | None:
        """A failure: the (event, fields) to log now, or None to hold it back."""
        self.failures += 1
        self._last = fields
        if self.failures == 1:
            self._since_s = self._summary_s = now_s
            return self.name, fields
        self._held += 1
        if now_s - self._summary_s >= self.summary_every_s:
            out = {**fields, "failures": self.failures, "held_back": self._held,
                   "for_s": round(now_s - self._since_s, 3)}
            self._summary_s = now_s
            self._held = 0
            return f"{self.name}_summary", out
        return None

    def succeeded(self, now_s: float) -> tuple[str, dict[str, Any]] | None:
        """A success: a ``_recovered`` line when it ends a run of failures."""
        if self.failures == 0:
            return None
        out = {"failures": self.failures, "for_s": round(now_s - self._since_s, 3),
               "last_error": self._last.get("reason") or self._last.get("error")}
        self.failures = self._held = 0
        self._last = {}
        return f"{self.name}_recovered", out
