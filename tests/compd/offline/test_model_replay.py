"""The bare-model replay as a library (`compd.offline.model_replay`): called with
a model, a record and a typed starting state, no command line in between."""

from __future__ import annotations

import typing

import numpy as np
import pytest

from compd.cli import build_parser
from compd.infiles import load_model
from compd.offline.model_replay import INIT_MODES, InitMode, replay_model, replay_with_init
from compd.offline.records import Record, RecordError
from tests.compd.offline.records_gen import inputs


def _record(period_s: float = 1.0, n: int = 1800) -> Record:
    cols = inputs(n, seed=5)
    return Record(path="<gen>", sha256="", time_s=cols["time_s"] * period_s,
                  period_s=period_s,
                  columns={"bearing": np.round(cols["bearing"], 1),
                           "ambient": np.round(cols["ambient"], 1)})


def test_each_starting_state_from_the_library() -> None:
    record = _record()
    bare = replay_model(load_model("sp2"), record)
    measured = bare + 7.5  # the machine was already 7.5 µm off when the record began
    rest = replay_with_init(load_model("sp2"), record, measured, "rest")
    steady = replay_with_init(load_model("sp2"), record, measured, "steady")
    estimate = replay_with_init(load_model("sp2"), record, measured, "estimate")
    assert np.array_equal(rest, bare)
    assert abs(float(np.mean(measured[:5] - steady[:5]))) < 1e-9  # starts at the level
    assert float(np.max(np.abs(estimate - measured))) < 1e-6  # the offset is estimated


def test_a_model_at_another_period_is_refused() -> None:
    with pytest.raises(RecordError, match="identified at 1 s"):
        replay_model(load_model("sp2"), _record(period_s=2.0))


def test_the_command_offers_the_librarys_starting_states() -> None:
    parser = build_parser()
    sub = next(a for a in parser._actions if a.choices and "replay" in a.choices)
    replay = sub.choices["replay"]  # type: ignore[index]
    init = next(a for a in replay._actions if a.dest == "init")
    assert tuple(init.choices or ()) == INIT_MODES == typing.get_args(InitMode)
