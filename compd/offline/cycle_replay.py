"""A record replayed through the daemon's own cycle (`compd.core.cycle.Cycle`):
each row a sample at its own time, planned and committed as written (the
controller accepts every write), so the figures are the offset the daemon
would have put in force: validation, model, fault policy, clamp, slew limit
and deadband, exactly as `compd run` steps them. The model's own output is
kept beside it (`model_um`, NaN where the cycle did not step the model).

The time is the record's (`time_s`, machine seconds): no clock is read, the
rows are the clock. No read-back (a record holds no controller).

`compd replay --config CONFIG` replays a record through it; without
`--config`, `compd replay` steps the bare model (the papers' figures).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from compd.core.cycle import WRITTEN, Cycle, CycleParams
from compd.core.validation import ChannelLimits
from compd.offline.records import Record
from drivers.base import Sample
from models.compensation import CompensationModel

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class CycleReplay:
    """What the daemon's cycle did at each row of a record."""

    #: the offset in force after each row (µm; what the controller holds)
    offset_um: FloatArray
    #: the model's output at each row (µm; NaN where the cycle did not step it)
    model_um: FloatArray
    #: the state each row recorded (`compd.core.faults.FaultState` names)
    states: tuple[str, ...]
    #: COMPLETE rows: the offset the model asks for is the offset in force
    in_force: npt.NDArray[np.bool_]


def replay_params(model: CompensationModel, *, limit_um: float, slew_um_s: float,
                  hold_s: float = 60.0, deadband_um: float = 0.0,
                  channels: Mapping[str, ChannelLimits] | None = None) -> CycleParams:
    """A cycle's parameters for a replay at the model's period: the output
    stage as given, every model channel accepted at any finite value unless
    `channels` gives its limits (a config's `[channels.*]`)."""
    limits = dict(channels) if channels is not None else {
        name: ChannelLimits(-math.inf, math.inf) for name in sorted(model.channels)}
    return CycleParams(period_s=model.period_s, hold_s=hold_s, limit_um=limit_um,
                       slew_um_s=slew_um_s, channels=limits, deadband_um=deadband_um,
                       readback=False)


def replay_cycle(params: CycleParams, model: CompensationModel, record: Record) -> CycleReplay:
    """Every row of `record` through one `Cycle` (see the module docstring)."""
    record.require(params.channels)
    # no controller to read back; the rows' time is machine time already
    cycle = Cycle(dataclasses.replace(params, readback=False, time_scale=1.0), model)
    n = len(record)
    offset, model_um = np.empty(n), np.full(n, math.nan)
    in_force = np.zeros(n, dtype=bool)
    states: list[str] = []
    for k, (t, row) in enumerate(zip(record.time_s.tolist(), record.samples(), strict=True)):
        samples = {name: Sample(row[name], t) for name in params.channels}
        cycle.plan(t, samples, wall_s=t)
        done = cycle.commit(WRITTEN)
        offset[k] = done.stage_um
        if done.model_um is not None:
            model_um[k] = done.model_um
        in_force[k] = done.in_force
        states.append(str(done.state))
    return CycleReplay(offset, model_um, tuple(states), in_force)
