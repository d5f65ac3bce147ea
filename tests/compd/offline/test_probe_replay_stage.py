"""`compd replay --probe-every-min` runs the daemon's own probe stage
(`compd.core.adaptation.ProbeStage`): on one record, the daemon's cycle fed
the same probes gives the same corrections, the same estimator and the same
offsets. The one difference is the row a probe's correction starts at: the
daemon applies a probe in the cycle that reads it; the replay, whose probe is
the very row it scores, from the next row on (a row is never corrected with
its own measurement)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from compd.cli import main
from compd.core.adaptation import AdaptationSettings, ProbeReading
from compd.core.cycle import WRITTEN, Cycle
from compd.infiles import load_model
from compd.offline.cycle_replay import replay_params
from compd.offline.model_replay import replay_model, replay_terms, replay_with_init
from compd.offline.probes import run_probes
from compd.offline.records import Record, read_record
from drivers.base import Sample
from models.adaptation import AdaptationParams
from tests.compd.offline.records_gen import inputs


def _record() -> Record:
    cols = inputs(3 * 3600, seed=4)
    return Record(path="<gen>", sha256="", time_s=cols["time_s"], period_s=1.0,
                  columns={"bearing": np.round(cols["bearing"], 1),
                           "ambient": np.round(cols["ambient"], 1)})


@pytest.mark.parametrize("gains", [False, True])
def test_the_replay_and_the_daemons_cycle_give_the_same_corrections(gains: bool) -> None:
    record = _record()
    model = load_model("sp2")
    simulated = replay_model(model, record)
    drift = 0.8 + 2.5 * record.time_s / record.time_s[-1]  # the model falls behind
    measured = simulated * 1.1 + drift if gains else simulated + drift
    params = AdaptationParams(apply_sigma=0.0, score_window=0, gains=gains)
    terms = replay_terms(model, record) if gains else None
    run = run_probes(simulated, measured, record.time_s, terms, every_s=600.0,
                     noise_um=0.3, seed=2, params=params)

    settings = AdaptationSettings("apply", "displacement", params)
    cycle_params = dataclasses.replace(replay_params(model, limit_um=1000.0,
                                                     slew_um_s=1000.0),
                                       adaptation=settings)
    cycle = Cycle(cycle_params, load_model("sp2"))
    daemon = np.empty(len(record))
    offset = np.empty(len(record))
    probe = ProbeReading(float("nan"), 0.0)  # what the controller shows at start
    rows = run.rows.tolist()
    for k, (t, row) in enumerate(zip(record.time_s.tolist(), record.samples(), strict=True)):
        if rows and rows[0] == k:  # a measuring cycle's value, read in this cycle
            probe = ProbeReading(float(run.values[int(probe.counter)]), probe.counter + 1.0)
            rows.pop(0)
        cycle.plan(t, {n: Sample(row[n], t) for n in cycle_params.channels}, wall_s=t,
                   probe=probe)
        offset[k] = cycle.commit(WRITTEN).stage_um
        assert cycle.probes is not None
        daemon[k] = cycle.probes.correction_um

    stage = cycle.probes
    assert stage is not None
    assert stage.accepted == int(run.accepted.sum()) == run.rows.size
    assert run.adapter.applied_moves >= run.rows.size - 1  # it followed the drift
    assert abs(daemon[-1]) > 2.0
    # the same estimator (without gains the replay counts the model as one term)
    state, replayed = stage.adapter.export_state(), run.adapter.export_state()
    assert {**state, "n_terms": 0} == {**replayed, "n_terms": 0}
    between = np.ones(len(record), dtype=bool)
    between[run.rows] = False
    daemon_adapted = simulated + daemon  # the model output and the daemon's correction
    assert np.array_equal(daemon_adapted[between], run.adapted[between])
    if not gains:  # the correction a probe sets is the same, a row earlier in the daemon
        assert np.array_equal(daemon[run.rows], daemon[run.rows + 1])
    assert np.max(np.abs(offset - (simulated + daemon))) <= 1e-9  # what the stage wrote


def test_the_probe_replay_is_a_library_call_on_a_typed_request(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The figures `compd replay --probe-every-min … --json` prints are the library's,
    called with a `ProbeRequest` and no argparse."""
    record = _record()
    model = load_model("sp2")
    measured = replay_model(model, record) + 1.0 + 2.0 * record.time_s / record.time_s[-1]
    data = tmp_path / "rec.csv"
    data.write_text("time_s,bearing,ambient,dz_um\n" + "".join(
        f"{t:g},{b!r},{a!r},{d!r}\n" for t, b, a, d in zip(
            record.time_s.tolist(), record.columns["bearing"].tolist(),
            record.columns["ambient"].tolist(), measured.tolist(), strict=True)))
    assert main(["replay", "sp2", str(data), "--column", "dz_um", "--probe-every-min", "15",
                 "--probe-noise-um", "0.2", "--apply-sigma", "0", "--score-window", "0",
                 "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)

    from compd.offline.probe_replay import ProbeRequest, replay_probes

    request = ProbeRequest(every_min=15.0, noise_um=0.2,
                           settings=(("apply_sigma", 0.0), ("score_window", 0.0)))
    read = read_record(str(data))
    simulated = replay_with_init(model, read, read.column("dz_um"), "estimate")
    run, figures = replay_probes(request, model, read, read.column("dz_um"), simulated, 0)
    assert run.adapter.applied_moves > 0
    assert printed["adapted"] == figures["adapted"]
    assert printed["crude"] == figures["crude"]
    assert printed["adaptation"]["apply_sigma"] == 0.0
