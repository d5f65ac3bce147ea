"""The invariants every fault test checks on EVERY cycle.

- the written offset is finite and |u| ≤ Umax, or, beyond a limit lowered
  since compd wrote what the controller holds (a reload), nearer to it than
  that: it only ever ramps in;
- |Δu| ≤ R·Δt, Δt the machine time since the previous cycle capped at 2·Ts
  (the output stage's cap), Δu measured against what the controller holds:
  the offset read back in this cycle when there is one, else the last
  written value that the controller accepted;
- at most one write per target per cycle;
- the heartbeat advances (by one, modulo) exactly on a complete valid cycle,
  and what is written to the controller is the cycle's heartbeat.

How: the autouse fixture `invariants` wraps `Cycle.plan` (every cycle of every
daemon and every pure run is seen, with its time and read-back; `Cycle.commit`
replaces the logged plan with its final row) and
`InvariantDriver` wraps a real driver to see every write the daemon sends.
A violation raises `AssertionError` at once (it propagates out of
`Daemon.run()`, which only catches driver errors) and is also kept in
`Invariants.violations`, asserted empty at teardown.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import pytest

from compd.core.cycle import HEARTBEAT_MODULO, WRITTEN, Cycle, Outcome, Plan, Row
from drivers.base import Driver, Sample

#: float32 registers and rounding: tolerance on the µm comparisons
EPS_UM = 1e-3


@dataclass
class CycleLog:
    """What one cycle did, for the figures."""

    now_s: float
    readback: float | None
    #: the cycle's plan, replaced by its row once committed
    result: Plan | Row
    #: output name -> value the driver was asked to write (controller units)
    written: dict[str, float] = field(default_factory=dict)
    write_ok: bool | None = None


@dataclass
class _Track:
    last_now_s: float | None = None
    held: float | None = None  # controller units
    cycles: list[CycleLog] = field(default_factory=list)


class Invariants:
    """Per-Cycle-instance invariant state and the log of every cycle."""

    def __init__(self) -> None:
        self.violations: list[str] = []
        self._tracks: dict[int, _Track] = {}
        self._cycles: dict[int, Cycle] = {}
        #: the cycle that stepped last (the one a driver write belongs to)
        self.current: Cycle | None = None

    # -- access ----------------------------------------------------------------

    def log(self, cycle: Cycle | None = None) -> list[CycleLog]:
        c = cycle if cycle is not None else self.current
        if c is None:
            return []
        return self._tracks[id(c)].cycles

    @property
    def total_cycles(self) -> int:
        return sum(len(t.cycles) for t in self._tracks.values())

    def _fail(self, msg: str) -> None:
        self.violations.append(msg)
        raise AssertionError(msg)

    # -- hooks -------------------------------------------------------------------

    def on_step(self, cycle: Cycle, now_s: float, readback: float | None,
                heartbeat_before: int, result: Plan) -> None:
        tr = self._tracks.setdefault(id(cycle), _Track())
        self._cycles[id(cycle)] = cycle  # keep it alive: ids stay unique
        self.current = cycle
        p = cycle.params
        seq = result.sequence
        scale = abs(p.units_per_um)
        # what the controller holds (µm): a lowered limit may find it beyond
        held_um = abs(readback) / scale if readback is not None and math.isfinite(readback) \
            else (abs(tr.held) / scale if tr.held is not None else 0.0)
        bound = max(p.limit_um, held_um)
        if not math.isfinite(result.stage_um) or abs(result.stage_um) > bound + EPS_UM:
            self._fail(f"seq {seq}: offset {result.stage_um} µm beyond ±{bound} "
                       f"(limit {p.limit_um}, held {held_um})")
        expected_hb = (heartbeat_before + 1) % HEARTBEAT_MODULO if result.inputs_valid \
            else heartbeat_before
        if result.heartbeat != expected_hb:
            self._fail(f"seq {seq}: heartbeat {heartbeat_before} -> {result.heartbeat} "
                       f"on a {'complete' if result.inputs_valid else 'incomplete'} cycle")
        if readback is not None and math.isfinite(readback):
            tr.held = readback
        dt = p.period_s if tr.last_now_s is None else now_s - tr.last_now_s
        tr.last_now_s = now_s
        log = CycleLog(now_s, readback, result)
        tr.cycles.append(log)
        if p.offset_name in result.writes:
            self._check_offset(cycle, tr, dt, result.writes[p.offset_name], seq)

    def _check_offset(self, cycle: Cycle, tr: _Track, dt: float, value: float,
                      seq: int) -> None:
        p = cycle.params
        scale = abs(p.units_per_um)
        bound = max(p.limit_um * scale, abs(tr.held) if tr.held is not None else 0.0)
        if not math.isfinite(value) or abs(value) > bound + EPS_UM * scale:
            self._fail(f"seq {seq}: written offset {value} beyond ±{p.limit_um} µm "
                       f"(or what the controller held, {tr.held})")
        if tr.held is not None:
            step_um = abs(value - tr.held) / scale
            allowed = p.slew_um_s * min(max(dt, 0.0), 2.0 * p.period_s)
            if step_um > allowed + EPS_UM:
                self._fail(f"seq {seq}: offset step {step_um:.4f} µm > R·Δt = "
                           f"{allowed:.4f} µm (held {tr.held}, writes {value})")

    def on_write(self, values: Mapping[str, float], ok: bool) -> None:
        cycle = self.current
        if cycle is None:
            self._fail("a write before any cycle stepped")
            return
        tr = self._tracks[id(cycle)]
        log = tr.cycles[-1]
        again = sorted(set(values) & set(log.written))
        if again:
            self._fail(f"seq {log.result.sequence}: written twice in one cycle: {again}")
        log.written.update(values)
        log.write_ok = ok if log.write_ok is None else (log.write_ok and ok)
        p = cycle.params
        for name, v in values.items():
            if name not in log.result.writes or log.result.writes[name] != v:
                self._fail(f"seq {log.result.sequence}: wrote {name}={v}, the cycle "
                           f"decided {log.result.writes.get(name)}")
        hb = p.heartbeat_name
        if hb is not None and hb in values and values[hb] != log.result.heartbeat:
            self._fail(f"seq {log.result.sequence}: heartbeat written "
                       f"{values[hb]} != {log.result.heartbeat}")
        if ok and p.offset_name in values:
            tr.held = values[p.offset_name]

    def on_commit(self, cycle: Cycle, row: Row) -> None:
        tr = self._tracks.get(id(cycle))
        if tr is not None and tr.cycles and tr.cycles[-1].result.sequence == row.sequence:
            tr.cycles[-1].result = row

    def write_outcome(self, cycle: Cycle, ok: bool) -> None:
        """Pure runs: the harness reports the (simulated) write's outcome."""
        self.current = cycle
        self.on_write(self.log(cycle)[-1].result.writes, ok)


@pytest.fixture(autouse=True)
def invariants(monkeypatch: pytest.MonkeyPatch) -> Iterator[Invariants]:
    """Check the invariants on every `Cycle.plan` of the test."""
    inv = watch(monkeypatch)
    yield inv
    assert not inv.violations, inv.violations


def watch(monkeypatch: pytest.MonkeyPatch) -> Invariants:
    """Check the invariants on every `Cycle.plan` until `monkeypatch` is undone (the
    fixture's work, for a test in a module whose other tests do without it)."""
    inv = Invariants()
    original, original_commit = Cycle.plan, Cycle.commit

    def plan(self: Cycle, now_s: float, samples: Mapping[str, Sample] | None,
             readback_offset_um: float | None = None, *,
             wall_s: float | None = None, **kw: Any) -> Plan:
        before = self.heartbeat
        result = original(self, now_s, samples, readback_offset_um, wall_s=wall_s, **kw)
        inv.on_step(self, now_s, readback_offset_um, before, result)
        return result

    def commit(self: Cycle, outcome: Outcome = WRITTEN) -> Row:
        row = original_commit(self, outcome)
        inv.on_commit(self, row)
        return row

    monkeypatch.setattr(Cycle, "plan", plan)
    monkeypatch.setattr(Cycle, "commit", commit)
    return inv


def run_pure(inv: Invariants, cycle: Cycle, now_s: float,
             samples: Mapping[str, Sample] | None, readback: float | None = None, *,
             wall_s: float | None = None, write_ok: bool = True) -> Plan | Row:
    """One pure cycle with its (simulated) write outcome, checked."""
    result: Plan | Row = cycle.plan(now_s, samples, readback, wall_s=wall_s)
    inv.write_outcome(cycle, write_ok)
    if write_ok:
        result = cycle.commit()
    return result


class InvariantDriver:
    """A real driver, seen: every write goes to the invariant checker (with
    its outcome); `before_read` (the plant) runs before each read with the
    read's index, so a test can change the controller's memory exactly
    between two samples."""

    def __init__(self, inner: Driver, inv: Invariants,
                 before_read: Any = None) -> None:
        self.inner = inner
        self.inv = inv
        self.protocol = inner.protocol
        self.before_read = before_read
        self.reads = 0

    @property
    def connected(self) -> bool:
        return self.inner.connected

    async def connect(self) -> None:
        await self.inner.connect()

    async def read(self, names: Sequence[str]) -> dict[str, Sample]:
        if self.before_read is not None:
            await self.before_read(self.reads)
        self.reads += 1
        return await self.inner.read(names)

    async def write(self, values: Mapping[str, float]) -> None:
        try:
            await self.inner.write(values)
        except BaseException:
            self.inv.on_write(values, ok=False)
            raise
        self.inv.on_write(values, ok=True)

    async def close(self) -> None:
        await self.inner.close()
