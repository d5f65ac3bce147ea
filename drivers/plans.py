"""Request plans kept per set of names (`PlanCache`).

A driver turns a set of names into requests (spans, runs, ranges) once and
reuses the plan: the daemon asks for the same handful of name sets every
cycle. The cache is cleared when it holds `size` plans, so a caller that
asks for ever new sets cannot grow it without bound.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Generic, TypeVar

P = TypeVar("P")

#: plans kept per cache (the daemon uses a handful of name sets)
PLAN_CACHE_SIZE = 64


class PlanCache(Generic[P]):
    """``cache(names)``: the plan `build` made for this tuple of names."""

    def __init__(self, build: Callable[[tuple[str, ...]], P],
                 size: int = PLAN_CACHE_SIZE) -> None:
        self._build = build
        self._size = size
        self._plans: dict[tuple[str, ...], P] = {}

    def __call__(self, names: Sequence[str]) -> P:
        key = tuple(names)
        plan = self._plans.get(key)
        if plan is None:
            plan = self._build(key)
            if len(self._plans) >= self._size:
                self._plans.clear()
            self._plans[key] = plan
        return plan


__all__ = ["PLAN_CACHE_SIZE", "PlanCache"]
