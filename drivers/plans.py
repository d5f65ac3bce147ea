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

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Generic, TypeVar

from drivers.footprint import Footprint, Space

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
    space, then address. An address without a footprint is left out."""
    placed: list[tuple[Footprint, int, str, A]] = []
    for i, (name, addr) in enumerate(items):
        fp = addr.footprint()
        if fp is not None:
            placed.append((fp, i, name, addr))
    placed.sort(key=lambda p: (p[0].space, p[0].start, p[1]))  # ties: in the order given
    runs: list[Run[A]] = []
    for fp, _, name, addr in placed:
        last = runs[-1] if runs else None
        if last is not None and last.space == fp.space and _joins(
                last, fp, max_gap, max_cells, join_overlaps):
            runs[-1] = Run(last.space, last.start, max(last.stop, fp.stop),
                           (*last.items, (name, addr)))
        else:
            runs.append(Run(fp.space, fp.start, fp.stop, ((name, addr),)))
    return runs


def _joins(run: Run[A], fp: Footprint, max_gap: int | None, max_cells: int | None,
           join_overlaps: bool) -> bool:
    gap = fp.start - run.stop
    if gap < 0 and not join_overlaps:
        return False
    if max_gap is not None and gap > max_gap:
        return False
    return max_cells is None or max(run.stop, fp.stop) - run.start <= max_cells

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


__all__ = ["PLAN_CACHE_SIZE", "PlanCache", "Run", "cover"]
