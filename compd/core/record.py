"""One cycle's row, as the recorder stores it (pure data).

The cycle builds it (`compd.core.cycle.Cycle.commit`, inside its `Row`),
the shell stamps the wall-clock time of recording (`dataclasses.replace`), and
`compd.runtime.recorder` stores it unchanged: one type from the cycle to the
database, no field copied by hand on the way.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

__all__ = ["RecordRow"]


@dataclass(frozen=True, slots=True)
class RecordRow:
    """One sample as the daemon saw it. `seq` is the daemon's cycle number
    (None when it has none), stored as ``cycle``: the table's ``seq`` is the
    recorder's own contiguous numbering, because a restart from an older
    checkpoint repeats cycle numbers. `offset_um` is the offset the controller
    confirmed (None when the cycle wrote none or the write failed),
    `attempted_um` the offset sent, confirmed or not; `state` a
    `compd.core.faults.FaultState` name; `complete` whether the cycle counts
    as complete (valid alone does not: a held output has valid inputs).
    Field order as in the table."""

    seq: int | None
    mono_s: float
    wall_s: float
    offset_um: float | None
    model_um: float | None
    state: str
    valid: bool
    channels: Mapping[str, float | None] = field(default_factory=dict)
    validity: Mapping[str, str | None] = field(default_factory=dict)
    contributions: Mapping[str, float] = field(default_factory=dict)
    attempted_um: float | None = None
    #: a probe that arrived this cycle (`compd.core.adaptation`): its values,
    #: innovation, accepted or refused and why, the estimator's bias after it
    probe: Mapping[str, Any] | None = None
    #: a COMPLETE cycle (`compd.core.cycle.offset_in_force`): the offset compd
    #: wants is the offset in force. False until the controller confirmed it.
    complete: bool = False
    #: [output.axes]: axis -> its part of the cycle (`compd.core.axes.AxisRow`),
    #: stored in table ``axes``; empty without per-axis outputs
    axes: Mapping[str, Any] = field(default_factory=dict)
