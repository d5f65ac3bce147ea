"""Rate-limited log lines of one kind (`Tally`): the first `BURST` a window one line each,
then one summary line per window with the count and the users and peers seen most."""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

#: refusals of one kind logged one line each per window; the rest summarised
BURST = 5
#: the summary window (s)
WINDOW_S = 60.0


@dataclass
class Tally:
    """Rate-limited log lines of one kind: `BURST` a window one each, then a count.

    `note` logs (or counts) one event; `flush` logs the summary of a window
    that is over (`note` calls it; the face's loop calls it once per window).
    """

    event: str
    log: Any
    clock: Callable[[], float] = time.monotonic
    burst: int = BURST
    window_s: float = WINDOW_S
    total: int = 0
    _start: float | None = None
    _logged: int = 0
    _suppressed: int = 0
    _users: Counter[str] = field(default_factory=Counter)
    _peers: Counter[str] = field(default_factory=Counter)

    def note(self, **fields: Any) -> None:
        now = self.clock()
        self.flush(now)
        self.total += 1
        if self._start is None:
            self._start = now
        if self._logged < self.burst:
            self._logged += 1
            self.log.warning(self.event, **fields)
            return
        self._suppressed += 1
        if "user" in fields:
            self._users[str(fields["user"])] += 1
        if "peer" in fields:
            self._peers[_host(str(fields["peer"]))] += 1

    def flush(self, now: float | None = None, *, force: bool = False) -> None:
        """Log the summary of a window that has ended (`force`: of this one, at
        the face's stop); start the next."""
        now = self.clock() if now is None else now
        if self._start is None or (now - self._start < self.window_s and not force):
            return
        if self._suppressed:
            extra: dict[str, Any] = {}
            if self._users:
                extra["users"] = dict(self._users.most_common(5))
            if self._peers:
                extra["peers"] = dict(self._peers.most_common(5))
            self.log.warning(f"{self.event}_summary", suppressed=self._suppressed,
                             window_s=self.window_s, total=self.total, **extra)
        self._start, self._logged, self._suppressed = None, 0, 0
        self._users.clear()
        self._peers.clear()


def _host(peer: str) -> str:
    """"('10.0.0.7', 50123)" -> "10.0.0.7" (summaries count hosts, not ports)."""
    text = peer.strip("()")
    return text.split(",")[0].strip("'\" ") if "," in text else text
