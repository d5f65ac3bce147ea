"""Request planning: the one planner (`cover`) and plans kept per set of names
(`PlanCache`).

`cover` groups named addresses into requests over their footprints
(`Address.footprint()`): one run per stretch of a memory space (a Modbus
unit's register table, an S7 DB, a PMC area), in address order. The S7,
Modbus and FOCAS codecs each state only their limits:

- reads cover gaps of unrequested cells up to `max_gap` (None: any gap) and
  overlapping values, while a run spans at most `max_cells` cells (None: no
  limit): Modbus 8 registers of gap and 125 per read, an S7 DB in one read,
  a PMC area up to 1024 bytes;
- writes join only back-to-back values (``max_gap=0, join_overlaps=False``),
  so a request never touches a cell it was not given.

A driver turns a set of names into requests once and reuses the plan: the
daemon asks for the same handful of name sets every cycle. The cache is
cleared when it holds `size` plans, so a caller that asks for ever new sets
cannot grow it without bound.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Generic, TypeVar

from drivers.footprint import Space

if TYPE_CHECKING:
    from drivers.addresses import Address

P = TypeVar("P")
A = TypeVar("A", bound="Address")


@dataclass(frozen=True, slots=True)
class Run(Generic[A]):
    """One request: cells ``[start, stop)`` of `space`, covering `items` (in
    address order)."""

    space: Space
    start: int
    stop: int
    items: tuple[tuple[str, A], ...]

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(name for name, _ in self.items)


def cover(items: Iterable[tuple[str, A]], *, max_gap: int | None = None,
          max_cells: int | None = None, join_overlaps: bool = True) -> list[Run[A]]:
    """Runs covering `items` by the rules of the module docstring, ordered by
    space, then address (ties in the order given). An address without a
    footprint is left out."""
    placed: list[tuple[Space, int, int, int, tuple[str, A]]] = []
    for i, item in enumerate(items):
        fp = item[1].footprint()
        if fp is not None:
            placed.append((fp.space, fp.start, i, fp.stop, item))
    placed.sort(key=lambda p: p[:3])
    gap_max = math.inf if max_gap is None else max_gap
    cells_max = math.inf if max_cells is None else max_cells
    gap_min = -math.inf if join_overlaps else 0
    runs: list[Run[A]] = []
    space: Space = ()
    start = stop = 0
    members: list[tuple[str, A]] = []
    for p_space, p_start, _, p_stop, item in placed:
        if members and p_space == space and gap_min <= p_start - stop <= gap_max \
                and max(stop, p_stop) - start <= cells_max:
            members.append(item)
            stop = max(stop, p_stop)
            continue
        if members:
            runs.append(Run(space, start, stop, tuple(members)))
        space, start, stop, members = p_space, p_start, p_stop, [item]
    if members:
        runs.append(Run(space, start, stop, tuple(members)))
    return runs


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
            self.put(key, plan)
        return plan

    def put(self, names: Sequence[str], plan: P) -> None:
        """Keep `plan` for `names` from now on (a driver that learnt a better one)."""
        if len(self._plans) >= self._size:
            self._plans.clear()
        self._plans[tuple(names)] = plan


__all__ = ["PLAN_CACHE_SIZE", "PlanCache", "Run", "cover"]
