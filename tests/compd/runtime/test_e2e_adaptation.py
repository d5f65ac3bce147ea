"""Probe-assisted adaptation end to end, through each of the four protocols,
in lockstep (`tests.harness`): the simulated machine and its controller
server on 127.0.0.1, the real daemon in-process reading and writing over the
real protocol, one daemon cycle per machine period.

The machine's measuring cycle is on (a probe every 30 machine minutes, 0.5 µm
noise), the daemon runs ``[adaptation] mode = "apply"`` with a model that
misses a fifth of the bearing's heat (what a calibration that aged looks
like). Along the way one probe is spoiled by 50 µm (a chip under the probe),
and the daemon is killed (as by SIGKILL: no shutdown, no final checkpoint,
uncommitted rows lost) between two probes and started again on the same state.

Checked, exactly (the run is deterministic): every probe the machine made is
in the recorder, once, in order (the daemon's first cycle, at rest, read the
counter's baseline); the spoiled one is refused by
the gate and nothing else is; the estimator resumed from its checkpoint (the
restarted daemon neither refused its state nor took a new baseline); the
offset the controller held never exceeds the limit nor moves faster than the
slew limit, across the kill too.
"""

from __future__ import annotations

import sqlite3
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from drivers.sim.machine import SimMachine
from drivers.sim.programs import make_program
from drivers.sim.registry import make_sim_controller
from models.modelfile import library_path
from tests.configs import lockstep_config, write_doc
from tests.harness import Lockstep

PROTOCOLS = ["opcua", "s7", "modbus", "focas"]
HOURS = 7.0
PERIOD_S = 60.0
LIMIT_UM = 200.0
SLEW_UM_S = 0.2
PROBE_EVERY_S = 1800.0
SPOILED_AT_S = 3 * 3600.0     # the 3 h probe
KILLED_AT_S = 4.25 * 3600.0   # between the 4 h and the 4.5 h probes


def _aged_model(work: Path) -> Path:
    """The plant's model with the bearing term's gain at 0.8 (an aged calibration)."""
    text = Path(str(library_path("sim_machine"))).read_text(encoding="utf-8")
    head, sep, rest = text.partition('name = "bearing"')
    rest = rest.replace("gain = 1.0", "gain = 0.8", 1)
    path = work / "aged.toml"
    path.write_text(head + sep + rest, encoding="utf-8")
    return path


async def _run(protocol: str, work: Path) -> dict[str, Any]:
    sim = make_sim_controller(protocol)
    await sim.start()
    machine = SimMachine(sim, program=make_program("spectrum", seed=5), seed=5,
                         period_s=PERIOD_S, repeat=False, record=True,
                         probe_every_s=PROBE_EVERY_S, probe_noise_um=0.5)
    doc = lockstep_config(sim, work, model=str(_aged_model(work)), period_s=PERIOD_S,
                          limit_um=LIMIT_UM, slew_um_s=SLEW_UM_S)
    doc["state"]["checkpoint_every"] = 5
    doc["recorder"]["commit_every"] = 5
    doc["adaptation"] = {"enabled": True, "mode": "apply", "measures": "residual",
                         # the aged model's miss follows the spindle program: a bias
                         # that may move 2 µm per √h (the default 0.3 suits a model
                         # that drifts slowly; `compd fit --adaptation` suggests one)
                         "bias_rw_um_per_sqrt_h": 2.0,
                         "probe_value": sim.probes["probe_value"].model_dump(),
                         "probe_counter": sim.probes["probe_counter"].model_dump()}
    rig = Lockstep(machine, write_doc(doc, work / "compd.toml"))
    try:
        await rig.start()
        await rig.run_until(SPOILED_AT_S - PERIOD_S)
        machine.spoil_next_probe(50.0)
        await rig.run_until(KILLED_AT_S)
        probes_before_kill = machine.probes
        await rig.kill9()
        await rig.start()
        await rig.run_until(HOURS * 3600.0)
        final_rc = await rig.stop()
    finally:
        await rig.close()
        await sim.stop()
    with sqlite3.connect(work / "state" / "samples.sqlite") as conn:
        probes = conn.execute("SELECT p.counter, p.accepted, p.reason, p.innovation_um,"
                              " p.bias_um, p.bias_sigma_um, s.mono_s FROM probes p"
                              " JOIN samples s ON s.seq = p.seq ORDER BY p.seq").fetchall()
    return {"history": machine.history_arrays(), "probes": probes, "final_rc": final_rc,
            "made": machine.probes, "before_kill": probes_before_kill,
            "log2": rig.logs[1].names()}


@pytest.mark.parametrize("protocol", PROTOCOLS)
async def test_adaptation_learns_refuses_a_bad_probe_and_resumes_after_kill9(
        protocol: str, tmp_path: Path) -> None:
    run = await _run(protocol, tmp_path)
    assert run["final_rc"] == 0
    made = run["made"]
    assert made == int(HOURS * 3600.0 / PROBE_EVERY_S)
    assert run["before_kill"] == int(KILLED_AT_S // PROBE_EVERY_S)
    probes = run["probes"]
    # every measurement is in the recorder, once, in order, up to the machine's
    # last: none missed across the kill, and none taken for a baseline again after
    # it (the restarted daemon knew the counter from its checkpoint)
    counters = [int(p[0]) for p in probes]
    assert counters == list(range(1, made + 1))
    # the spoiled probe (the 3 h one, the 6th) was refused by the gate, nothing else was
    refused = [(int(p[0]), p[2]) for p in probes if p[1] == 0]
    assert refused == [(int(SPOILED_AT_S / PROBE_EVERY_S), "gate")], refused
    spoiled = next(p for p in probes if p[1] == 0)
    assert spoiled[3] > 30.0
    accepted = [p for p in probes if p[1] == 1]
    assert len(accepted) == made - 1
    # the estimator resumed from the checkpoint (not started afresh: that is logged)
    assert "checkpoint_restored" in run["log2"]
    assert "adaptation_state_refused" not in run["log2"]
    after_kill = [p for p in accepted if int(p[0]) > run["before_kill"]]
    assert after_kill and abs(after_kill[0][4]) > 0.5  # weighed with the learnt bias
    assert abs(accepted[-1][4]) > 0.5  # a bias learnt (the aged model misses heat)
    # the limits at the tool, across everything (the controller held what compd
    # wrote): one daemon write per plant period, so one slew step at most
    offset = run["history"]["offset_um"]
    assert np.all(np.isfinite(offset)) and np.max(np.abs(offset)) <= LIMIT_UM
    step = np.abs(np.diff(offset))
    assert float(np.max(step)) <= SLEW_UM_S * PERIOD_S + 1e-6
