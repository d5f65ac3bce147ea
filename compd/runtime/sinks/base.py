"""The loop's side of a sink: `Tick`, what one cycle left, and `CycleSink`.

A sink is opened before the first cycle (`open`, with the config at start), fed every cycle's `Tick`
in the loop's thread (`feed`: cheap, never waits; an exception is logged as a
``cycle_error`` of its `stage` and the cycle goes on), told when a SIGHUP
reload swapped a new config in (`reload`), and closed when the loop ends
(`close`). The config in force is read from the tick, never kept from `open`:
a sink keeps only its resources (a file, a server) and what it counts. Sinks
do not know each other: what one needs of the cycle is in the report.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:
    from compd.config.loader import LoadedConfig
    from compd.core.plan import Row
    from compd.runtime.reload import Changes
    from drivers.base import Sample

__all__ = ["CycleSink", "StateSource", "Tick"]


class StateSource(Protocol):
    """What the checkpoint saves: the cycle's state, exported when a save is due
    (`compd.core.cycle.Cycle.export_state`, a new dict each call)."""

    def export_state(self) -> dict[str, Any]: ...


@dataclass(frozen=True, slots=True)
class Tick:
    """One cycle as the sinks see it."""

    cfg: LoadedConfig
    #: the committed cycle (`Cycle.commit`): its final record, and the
    #: `snapshot` the faces read (the confirmed offset, the operator's hold,
    #: the adaptation estimator)
    row: Row
    #: the cycle's monotonic time (`compd.runtime.clock.Instant.mono_s`; its machine
    #: and wall-clock time are the row's `machine_s` and `wall_s`)
    mono_s: float
    #: the channels as read (None: the read failed)
    samples: dict[str, Sample] | None
    #: the controller confirmed this cycle's writes (a dry run: always)
    confirmed: bool
    #: whether the last read heard the controller (None: no read yet)
    read_ok: bool | None
    #: the cycle that committed the row, whose state the checkpoint saves
    state: StateSource


class CycleSink(Protocol):
    """A consumer of the cycle's ticks (subclass it for the no-op defaults)."""

    #: the stage named in its ``cycle_error`` lines
    stage: str

    async def open(self, cfg: LoadedConfig) -> None:
        return None

    def feed(self, tick: Tick) -> None: ...

    def reload(self, cfg: LoadedConfig, changes: Changes) -> None:
        return None

    async def close(self) -> None:
        return None
