"""A record through the daemon's own cycle (`compd.offline.cycle_replay`): the
model output is the bare replay's, the offset is what the output stage lets
through (slew limit, hold on a bad row)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from compd.commands.replay import replay_model
from compd.infiles import load_model
from compd.offline.cycle_replay import replay_cycle, replay_params
from compd.offline.records import Record

from .records_gen import inputs


def _record(hours: float = 2.0) -> Record:
    n = int(hours * 3600)
    cols = inputs(n, seed=3)
    return Record(path="<gen>", sha256="", time_s=cols["time_s"], period_s=1.0,
                  columns={"bearing": np.round(cols["bearing"], 1),
                           "ambient": np.round(cols["ambient"], 1)})


def test_a_generous_output_stage_writes_the_bare_models_output() -> None:
    record = _record()
    bare = replay_model(load_model("sp2"), record)
    model = load_model("sp2")
    out = replay_cycle(replay_params(model, limit_um=1000.0, slew_um_s=1000.0), model, record)
    assert np.array_equal(out.model_um, bare)  # stepped exactly as the bare replay
    assert np.max(np.abs(out.offset_um - bare)) <= 1e-9
    assert out.in_force.all() and set(out.states) == {"ok"}


def test_the_slew_limit_holds_on_every_row() -> None:
    record = _record()
    model = load_model("sp2")
    slew = 0.002  # µm/s: slower than the model moves while the spindle heats
    out = replay_cycle(replay_params(model, limit_um=1000.0, slew_um_s=slew), model, record)
    steps = np.abs(np.diff(out.offset_um))
    assert steps.max() <= slew * record.period_s + 1e-12
    assert np.max(np.abs(out.offset_um - out.model_um)) > 1.0  # it lagged the model


def test_a_bad_row_holds_the_offset_and_leaves_the_model_unstepped() -> None:
    record = _record(0.5)
    bearing = record.columns["bearing"].copy()
    bearing[600] = math.nan
    record = Record(path=record.path, sha256="", time_s=record.time_s, period_s=1.0,
                    columns={**record.columns, "bearing": bearing})
    model = load_model("sp2")
    out = replay_cycle(replay_params(model, limit_um=1000.0, slew_um_s=1000.0), model, record)
    assert out.states[600] == "hold" and not out.in_force[600]
    assert math.isnan(out.model_um[600])
    assert out.offset_um[600] == out.offset_um[599]
    assert out.states[601] == "ok"


def test_a_record_without_a_model_channel_is_refused() -> None:
    from compd.offline.records import RecordError

    record = _record(0.1)
    record = Record(path="<gen>", sha256="", time_s=record.time_s, period_s=1.0,
                    columns={"bearing": record.columns["bearing"]})
    model = load_model("sp2")
    with pytest.raises(RecordError, match="ambient"):
        replay_cycle(replay_params(model, limit_um=100.0, slew_um_s=1.0), model, record)
