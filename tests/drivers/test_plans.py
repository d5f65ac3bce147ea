"""The one request planner (`drivers.plans.cover`): each codec's requests are
what its own planner made before there was one planner (the references
below, kept as the codecs had them), and a write never touches a cell it was
not given."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from hypothesis import given
from hypothesis import strategies as st

from drivers import focas_codec, modbus_codec, s7_codec
from drivers.addresses import FocasPmcAddress, ModbusAddress, S7Address
from drivers.encodings import MODBUS_TYPES, PMC_ENCODINGS, S7_TYPES
from drivers.plans import cover

# -- the planners as each codec had its own (references) -------------------------


def old_s7_read_spans(addresses: Mapping[str, S7Address]) -> list[tuple[Any, ...]]:
    by_db: dict[int, list[str]] = {}
    for name, addr in addresses.items():
        by_db.setdefault(addr.db, []).append(name)
    spans = []  # (names as a set: they were in the order given, now in address order)
    for db, names in sorted(by_db.items()):
        start = min(addresses[n].offset for n in names)
        end = max(addresses[n].offset + addresses[n].size for n in names)
        spans.append((db, start, end - start, frozenset(names)))
    return spans


def old_s7_write_runs(items: Iterable[tuple[str, S7Address]]) -> list[tuple[Any, ...]]:
    runs: list[tuple[int, int, int, tuple[str, ...]]] = []
    for name, addr in sorted(items, key=lambda it: (it[1].db, it[1].offset)):
        last = runs[-1] if runs else None
        if last is not None and last[0] == addr.db and last[1] + last[2] == addr.offset:
            runs[-1] = (last[0], last[1], last[2] + addr.size, (*last[3], name))
        else:
            runs.append((addr.db, addr.offset, addr.size, (name,)))
    return runs


def old_pmc_runs(items: Iterable[tuple[str, FocasPmcAddress]], *,
                 write: bool) -> list[tuple[Any, ...]]:
    ranges: list[tuple[str, int, int, tuple[str, ...]]] = []
    for name, a in sorted(items, key=lambda it: (it[1].area, it[1].address)):
        end = a.address + a.size - 1
        last = ranges[-1] if ranges else None
        joins = last is not None and last[0] == a.area and (
            last[2] + 1 == a.address if write
            else end - last[1] < focas_codec.MAX_RANGE_BYTES)
        if last is not None and joins:
            ranges[-1] = (a.area, last[1], max(last[2], end), (*last[3], name))
        else:
            ranges.append((a.area, a.address, end, (name,)))
    return ranges


def old_modbus_reads(items: Iterable[tuple[str, ModbusAddress]], max_gap: int,
                     max_count: int) -> list[tuple[Any, ...]]:
    groups: dict[tuple[int, str], list[tuple[str, ModbusAddress]]] = {}
    for name, addr in items:
        groups.setdefault((addr.unit, addr.kind), []).append((name, addr))
    spans: list[tuple[Any, ...]] = []
    for (unit, kind), members in sorted(groups.items()):
        members.sort(key=lambda m: (m[1].address, m[1].count))
        current: list[str] = []
        start = end = 0
        for name, addr in members:
            a_end = addr.address + addr.count
            if current and addr.address - end <= max_gap and \
                    max(end, a_end) - start <= max_count:
                current.append(name)
                end = max(end, a_end)
                continue
            if current:
                spans.append((unit, kind, start, end - start, tuple(current)))
            current, start, end = [name], addr.address, a_end
        if current:
            spans.append((unit, kind, start, end - start, tuple(current)))
    return spans


def old_modbus_writes(items: list[tuple[str, ModbusAddress, list[int]]]
                      ) -> list[tuple[Any, ...]]:
    out: list[tuple[Any, ...]] = []
    current: list[str] = []
    words: list[int] = []
    unit = start = 0
    for name, addr, regs in sorted(items, key=lambda it: (it[1].unit, it[1].address)):
        if current and addr.unit == unit and addr.address == start + len(words) and \
                len(words) + len(regs) <= modbus_codec.MAX_WRITE_REGISTERS:
            current.append(name)
            words.extend(regs)
            continue
        if current:
            out.append((unit, start, len(words), tuple(current), words))
        current, words, unit, start = [name], list(regs), addr.unit, addr.address
    if current:
        out.append((unit, start, len(words), tuple(current), words))
    return out


# -- strategies: small address ranges, so that neighbours, gaps and overlaps occur --

def _named(addresses: st.SearchStrategy[Any]) -> st.SearchStrategy[dict[str, Any]]:
    return st.lists(addresses, max_size=10).map(
        lambda xs: {f"n{i}": a for i, a in enumerate(xs)})


_S7 = _named(st.builds(lambda o, t, d: S7Address(db=d, offset=o, type=t),
                       st.integers(0, 20), st.sampled_from(sorted(S7_TYPES)),
                       st.integers(1, 2)))
_PMC = _named(st.builds(lambda a, t, area: FocasPmcAddress(area=area, address=a, type=t),
                        st.integers(0, 1100), st.sampled_from(sorted(PMC_ENCODINGS)),
                        st.sampled_from(["D", "R"])))
_MB = _named(st.builds(lambda a, t, u, k: ModbusAddress(address=a, type=t, unit=u, kind=k),
                       st.integers(0, 140), st.sampled_from(sorted(MODBUS_TYPES)),
                       st.integers(1, 2), st.sampled_from(["holding", "input"])))


@given(_S7)
def test_s7_requests_are_the_codecs_own(addresses: dict[str, S7Address]) -> None:
    spans = s7_codec.read_spans(addresses)
    assert [(s.db, s.start, s.size, frozenset(s.names)) for s in spans] == \
        old_s7_read_spans(addresses)
    runs = s7_codec.write_runs(addresses.items())
    assert [(r.db, r.start, r.size, r.names) for r in runs] == \
        old_s7_write_runs(addresses.items())


@given(_PMC)
def test_pmc_requests_are_the_codecs_own(addresses: dict[str, FocasPmcAddress]) -> None:
    items = list(addresses.items())
    assert [(r.area, r.start, r.end, r.names) for r in focas_codec.read_ranges(items)] == \
        old_pmc_runs(items, write=False)
    assert [(r.area, r.start, r.end, r.names) for r in focas_codec.write_runs(items)] == \
        old_pmc_runs(items, write=True)


@given(_MB, st.integers(0, 10))
def test_modbus_requests_are_the_codecs_own(addresses: dict[str, ModbusAddress],
                                            max_gap: int) -> None:
    items = list(addresses.items())
    spans = modbus_codec.plan_reads(items, max_gap=max_gap)
    # (names as sets: values starting at one register were ordered by width, now as given)
    assert [(s.unit, s.kind, s.start, s.count, frozenset(n for n, _ in s.items))
            for s in spans] == [(*s[:4], frozenset(s[4])) for s in old_modbus_reads(
                items, max_gap, modbus_codec.MAX_READ_REGISTERS)]
    held = [(n, a, list(range(a.count))) for n, a in items if a.kind == "holding"]
    got = [(s.unit, s.start, s.count, tuple(n for n, _ in s.items), words)
           for s, words in modbus_codec.plan_writes(held)]
    assert got == old_modbus_writes(held)


@given(_MB, st.integers(0, 10), st.integers(1, 130))
def test_a_write_run_is_exactly_its_values_and_a_read_covers_its_own(
        addresses: dict[str, ModbusAddress], max_gap: int, max_cells: int) -> None:
    items = list(addresses.items())
    for run in cover(items, max_gap=0, join_overlaps=False):
        cells = [c for _, a in run.items for c in a.footprint().cells()]
        assert cells == list(range(run.start, run.stop))  # back to back, nothing between
    reads = cover(items, max_gap=max_gap, max_cells=max_cells)
    assert sorted(n for run in reads for n in run.names) == sorted(addresses)
    for run in reads:
        for _, a in run.items:
            fp = a.footprint()
            assert fp.space == run.space and run.start <= fp.start and fp.stop <= run.stop
        if len(run.items) > 1:
            assert run.stop - run.start <= max_cells
