"""Every per-axis output of one cycle, driven together (pure).

`AxisBank` plans, writes and commits each configured axis
(`compd.core.axes.AxisOutput`) in the cycle's one read and one write, carries
their state over a reload, and builds the axes word a PLC reads (which axes are
in force, alarmed, holding or ramping, and a LIFE bit toggled in every word).
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType
from typing import Any

from compd.core.axes import AxisOutput
from compd.core.axis_params import AxisParams, AxisRow
from compd.core.events import Event
from compd.core.output import AXES_NIBBLE, AXIS_INDEX, AxesStatus, Status

__all__ = ["AxisBank"]

_LIFE = int(AxesStatus.LIFE)
_ALARM, _HOLDING = int(Status.ALARM), int(Status.HOLDING)
_RAMPING = int(Status.RAMPING) | int(Status.SHUTDOWN)


def _word_bits(axis: str) -> tuple[int, int, int, int] | None:
    """An axis's IN_FORCE, ALARM, HOLDING and RAMPING bits in the axes word; None:
    the tool direction, no bits of its own."""
    if axis not in AXIS_INDEX:
        return None
    bit = 1 << AXIS_INDEX[axis]
    return (bit << AXES_NIBBLE["in_force"], bit << AXES_NIBBLE["alarm"],
            bit << AXES_NIBBLE["holding"], bit << AXES_NIBBLE["ramping"])


class AxisBank:
    """Every configured axis of a cycle (`compd.core.axes`)."""

    def __init__(self, axes: tuple[AxisParams, ...], *, hold_s: float, period_s: float,
                 readback: bool, state: Mapping[str, Any] | None = None) -> None:
        st = state if isinstance(state, Mapping) else {}
        self.readback = readback
        self.axes = [AxisOutput(p, hold_s, period_s, readback,
                                s if isinstance(s := st.get(p.axis), Mapping) else None)
                     for p in axes]
        #: every parameter's output name (read back beside the offset), made once
        self._names = tuple(n for a in self.axes for n in a.names)
        #: each axis and its bits in the axes word (`status_word`), made once
        self._word = [(a, bits) for a in self.axes if (bits := _word_bits(a.p.axis))]
        #: the axes word's LIFE bit, toggled in every word planned
        self._life = False

    def __bool__(self) -> bool:
        return bool(self.axes)

    @property
    def names(self) -> tuple[str, ...]:
        """Every parameter's output name (read back beside the offset)."""
        return self._names

    def export_state(self) -> dict[str, Any]:
        return {a.p.axis: a.export_state() for a in self.axes}

    def begin_shutdown(self) -> None:
        for a in self.axes:
            a.health.begin_shutdown()

    def plan(self, now_s: float, dt: float, values: Mapping[str, float],
             validity: Mapping[str, str | None], *, answered: bool,
             readback: Mapping[str, float | None] | None, off: str | None, hold: bool,
             write: bool, events: list[Event]) -> dict[str, float]:
        """Every axis's part of the cycle's plan: its writes (none when `write` is
        false: a recorder-only or dry run)."""
        writes: dict[str, float] = {}
        # the channels invalid this cycle, once for every axis's gate
        invalid = [ch for ch, why in validity.items() if why is not None]
        for a in self.axes:
            pos = a.p.position
            present = (values[pos] if answered and pos is not None
                       and validity.get(pos) is None and pos in values else None)
            full = a.judge(readback if self.readback else None, off=off, events=events,
                           position_mm=present)
            a.plan(now_s, dt, values, validity, answered, hold=hold, events=events,
                   invalid=invalid)
            if write:
                writes.update(a.writes(full, self.readback, events))
        return writes

    def status_word(self) -> int:
        """This cycle's axes word (`compd.core.output.AxesStatus`), after `plan`: per
        axis IN_FORCE (the line the controller confirmed last cycle is what the
        models want, and is written again in this write), ALARM, HOLDING and
        RAMPING (or shutting down) from the axis's own status word; LIFE toggles
        on every call, so a PLC sees the cycle run whatever the inputs."""
        self._life = not self._life
        word = _LIFE if self._life else 0
        # the tool direction has no bits of its own (not in `_word`)
        for a, (in_force, alarm, holding, ramping) in self._word:
            status = a.status
            if a.in_force and a.writing and a.cause.healthy:
                word |= in_force
            if status & _ALARM:
                word |= alarm
            if status & _HOLDING:
                word |= holding
            if status & _RAMPING:
                word |= ramping
        return word

    def carry_over(self, old: AxisBank, *, same_outputs: bool) -> None:
        """Continue `old`'s axes across a reload (this bank built from its exported
        state): each axis still configured keeps its fault policy's timer and state
        (a hold goes on toward its ramp), and while the outputs are the same its
        stopped writes, whether its line was in force and its reference position
        written; the axes word's LIFE bit toggles on from where it was."""
        before = {a.p.axis: a for a in old.axes}
        self._life = old._life
        for a in self.axes:
            was = before.get(a.p.axis)
            if was is None:
                continue
            a.health.carry_over(was.health, outputs_same=same_outputs)
            if same_outputs:
                a.in_force = was.in_force
                a.reference_written = was.reference_written

    def settled(self) -> bool:
        """A ramp-to-zero shutdown is done for every axis (or cannot write any more)."""
        return all(a.health.write_stopped or a.health.controller_off is not None
                   or a.value.stage.held or a.slope.stage.held
                   or (a.value.stage.current_um == 0.0 and a.slope.stage.current_um == 0.0)
                   for a in self.axes)

    def commit(self, ok: bool, outputs: tuple[str, ...], permanent: bool, reason: str,
               later: list[Event]) -> tuple[Mapping[str, AxisRow], tuple[Event, ...]]:
        """Close every axis's part of the cycle; the axes' rows and write events."""
        rows: dict[str, AxisRow] = {}
        events: list[Event] = []
        for a in self.axes:
            confirmed, failed, evs = a.commit(ok, outputs, permanent, reason, later)
            events.extend(evs)
            rows[a.p.axis] = a.row(confirmed, failed)
        return MappingProxyType(rows), tuple(events)
