"""Probe-assisted adaptation end to end, through each of the four protocols.

The simulated machine on 127.0.0.1 with its measuring cycle on (a probe every
30 machine minutes, 0.5 µm noise), the real `compd run` process against it
with ``[adaptation] mode = "apply"`` and a model that misses a fifth of the
bearing's heat (what a calibration that aged looks like). Along the way one
probe is spoiled by 50 µm (a chip under the probe), and the daemon is killed
with SIGKILL between two probes and started again.

Checked: probes arrive and are learnt, the spoiled one is refused; the offset
the controller holds never exceeds the limit nor moves faster than the slew
limit, across the kill too; the estimator resumed from its checkpoint (the
restarted daemon's first probe is weighed with the learnt bias, not from 0);
every probe is in the recorder.
"""

from __future__ import annotations

import asyncio
import signal
import sqlite3
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from compd.offline.demo import daemon_config, start_daemon, start_daemon_at_rest
from drivers.sim.machine import SimMachine
from drivers.sim.programs import make_program
from drivers.sim.registry import make_sim_controller
from models import tomltext
from models.modelfile import library_path

PROTOCOLS = ["opcua", "s7", "modbus", "focas"]
HOURS = 7.0
WALL_S = 14.0
LIMIT_UM = 200.0
SLEW_UM_S = 0.2
PROBE_EVERY_S = 1800.0

pytestmark = pytest.mark.timeout(240)


def _aged_model(work: Path) -> Path:
    """The plant's model with the bearing term's gain at 0.8 (an aged calibration)."""
    text = Path(str(library_path("sim_machine"))).read_text(encoding="utf-8")
    head, sep, rest = text.partition('name = "bearing"')
    rest = rest.replace("gain = 1.0", "gain = 0.8", 1)
    path = work / "aged.toml"
    path.write_text(head + sep + rest, encoding="utf-8")
    return path


async def _until(machine: SimMachine, t_s: float) -> None:
    while machine.time_s < t_s:  # noqa: ASYNC110
        await asyncio.sleep(0.002)


async def _run(protocol: str, work: Path) -> dict[str, Any]:
    time_scale = HOURS * 3600.0 / WALL_S
    sim = make_sim_controller(protocol)
    await sim.start()
    machine = SimMachine(sim, program=make_program("spectrum", seed=5), seed=5, period_s=60.0,
                         speedup=time_scale, repeat=False, record=True,
                         probe_every_s=PROBE_EVERY_S, probe_noise_um=0.5)
    doc = daemon_config(sim, model=str(_aged_model(work)), period_s=60.0,
                        time_scale=time_scale, state_dir=work / "state", limit_um=LIMIT_UM,
                        slew_um_s=SLEW_UM_S)
    doc["state"]["checkpoint_every"] = 5
    doc["recorder"]["commit_every"] = 5
    doc["adaptation"] = {"enabled": True, "mode": "apply", "measures": "residual",
                         # the aged model's miss follows the spindle program: a bias
                         # that may move 2 µm per √h (the default 0.3 suits a model
                         # that drifts slowly; `compd fit --adaptation` suggests one)
                         "bias_rw_um_per_sqrt_h": 2.0,
                         "probe_value": sim.probes["probe_value"].model_dump(),
                         "probe_counter": sim.probes["probe_counter"].model_dump()}
    config = work / "compd.toml"
    config.write_text(tomltext.dumps(doc), encoding="utf-8")
    daemons: list[asyncio.subprocess.Process] = []
    marks: dict[str, float] = {}
    try:
        daemons.append(await start_daemon_at_rest(machine, config, work / "daemon-1.log",
                                                  work / "notify-1"))
        runner = asyncio.ensure_future(machine.run(until_s=HOURS * 3600.0))
        try:
            await _until(machine, 2.9 * 3600)
            machine.spoil_next_probe(50.0)  # the 3 h probe
            marks["spoiled"] = machine.time_s
            await _until(machine, 4.25 * 3600)  # between the 4 h and the 4.5 h probes
            daemons[-1].send_signal(signal.SIGKILL)
            await daemons[-1].wait()
            marks["kill9"] = machine.time_s
            daemons.append(await start_daemon(config, work / "daemon-2.log",
                                              work / "notify-2"))
            await runner
        finally:
            if not runner.done():
                runner.cancel()
                await asyncio.gather(runner, return_exceptions=True)
    finally:
        for d in daemons:
            if d.returncode is None:
                d.send_signal(signal.SIGTERM)
                await asyncio.wait_for(d.wait(), 15)
        await sim.stop()
    with sqlite3.connect(work / "state" / "samples.sqlite") as conn:
        probes = conn.execute("SELECT p.counter, p.accepted, p.reason, p.innovation_um,"
                              " p.bias_um, p.bias_sigma_um, s.mono_s FROM probes p"
                              " JOIN samples s ON s.seq = p.seq ORDER BY p.seq").fetchall()
    return {"history": machine.history_arrays(), "probes": probes, "marks": marks,
            "final_rc": daemons[-1].returncode, "made": machine.probes,
            "log2": (work / "daemon-2.log").read_text(errors="replace")}


@pytest.mark.parametrize("protocol", PROTOCOLS)
async def test_adaptation_learns_refuses_a_bad_probe_and_resumes_after_kill9(
        protocol: str, tmp_path: Path) -> None:
    run = await _run(protocol, tmp_path)
    assert run["final_rc"] == 0
    probes = run["probes"]
    # every measurement after the first (a baseline) is in the recorder, once, and
    # none was taken for a baseline again after the kill: the restarted daemon knew
    # the counter from its checkpoint
    counters = [int(p[0]) for p in probes]
    assert counters == list(range(counters[0], counters[0] + len(counters)))
    # (the machine's last measurement, at its very end, may come after the daemon's
    # last read)
    assert run["made"] - 1 <= counters[-1] <= run["made"]
    assert len(counters) >= run["made"] - 2
    accepted = [p for p in probes if p[1] == 1]
    refused = [p for p in probes if p[1] == 0]
    assert len(accepted) >= 8
    # the spoiled probe was refused by the gate, nothing else was
    assert [(p[2], p[3] > 30.0) for p in refused] == [("gate", True)], refused
    # the estimator resumed from the checkpoint (not started afresh: that would
    # have been logged, and the counter would have restarted with a baseline)
    assert "adaptation_state_refused" not in run["log2"]
    assert abs(accepted[-1][4]) > 0.5  # a bias learnt (the aged model misses heat)
    # the limits at the tool, across everything (the controller held what compd wrote)
    h = run["history"]
    offset = h["offset_um"]
    assert np.all(np.isfinite(offset)) and np.max(np.abs(offset)) <= LIMIT_UM
    step = np.abs(np.diff(offset))
    assert float(np.max(step)) <= 2.0 * SLEW_UM_S * 60.0 + 1e-6
