"""Capped exponential backoff for reconnect attempts (monotonic clock)."""

from __future__ import annotations

import time
from collections.abc import Callable


class Backoff:
    """Decides when the next reconnect attempt may run.

    After each failure the delay doubles from `initial_s` up to `cap_s`;
    a success resets it. `ready()` tells whether an attempt is due now, so a
    read on a down link can fail fast instead of waiting.
    """

    def __init__(self, initial_s: float = 0.1, cap_s: float = 5.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if initial_s <= 0 or cap_s < initial_s:
            raise ValueError("backoff needs 0 < initial_s <= cap_s")
        self.initial_s = initial_s
        self.cap_s = cap_s
        self._clock = clock
        self._delay_s = 0.0
        self._next_s = float("-inf")
        self.failures = 0

    def ready(self) -> bool:
        return self._clock() >= self._next_s

    def failed(self) -> None:
        self.failures += 1
        self._delay_s = self.initial_s if self._delay_s == 0.0 else min(
            self._delay_s * 2.0, self.cap_s)
        self._next_s = self._clock() + self._delay_s

    def succeeded(self) -> None:
        self.failures = 0
        self._delay_s = 0.0
        self._next_s = float("-inf")

    @property
    def delay_s(self) -> float:
        return self._delay_s
