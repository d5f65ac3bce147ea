"""A first calibration run without a model, end to end: a recorder-only config
(no [model], ``[output] enabled = false``) against the real simulated Modbus
controller on the stepped clock reads, validates and records every cycle, writes
nothing at all to the controller (no offset, heartbeat or status: its holding
registers keep the values they had), `compd check` accepts the config, and
`compd fit` identifies a model from the database the run left.
"""

from __future__ import annotations

import asyncio
import json
import math
import tomllib
from pathlib import Path
from typing import Any

import pytest

from compd.cli import main as cli
from compd.config.loader import parse_config
from compd.core.health import Cause
from compd.offline.demo import daemon_config
from drivers.sim.modbus_server import ModbusSimController
from models import tomltext
from tests.configs import CONNECT_TIMEOUT_S, REQUEST_TIMEOUT_S
from tests.faults.daemon_rig import DaemonRig
from tests.faults.invariants import Invariants, invariants

__all__ = ["invariants"]  # the autouse fixture, imported to be active here

TAU_S = 120.0  # the growth's lag behind the bearing (first order, s)
GAIN_UM_K = 3.0  # µm of growth per K of bearing above ambient


#: real seconds per machine second (a time scale of 1/20): on the stepped clock real
#: time is the clock's, except for the read's timeout, which may then be 10 s
REAL_S_PER_MACHINE_S = 20.0


#: one read stalls this long (real s), longer than the bound on a read at a real period
#: of 1 s (max(period, 2·0.45 s)): a loaded machine's stall, not a missing sample
STALL_S = 1.2
STALL_AT = 1000


def _recorder_doc(sim: ModbusSimController, tmp_path: Path) -> dict[str, Any]:
    """A read timed out is a row without values, which `compd fit` rightly refuses
    (a missing sample is not filled in): of 2,400 reads on a loaded machine not one
    may meet its timeout by chance, so a read has 10 real seconds (at most half the
    real period), not the 0.45 s a 1 s real period allows."""
    doc = daemon_config(sim, model="sp2", period_s=1.0, time_scale=1.0 / REAL_S_PER_MACHINE_S,
                        state_dir=tmp_path / "state", extra_channels=("growth_um",))
    doc["controller"]["timeout_s"] = REQUEST_TIMEOUT_S
    doc["controller"]["connect_timeout_s"] = CONNECT_TIMEOUT_S
    del doc["model"]
    doc["output"] = {"enabled": False}
    doc["recorder"] = {"enabled": True, "path": "calib.sqlite", "commit_every": 10,
                       "retention_days": 0}
    doc["channels"]["growth_um"].update({"unit": "um", "range": [-1000.0, 1000.0]})
    return doc


async def test_recorder_only_records_what_fit_reads_and_writes_nothing(
        tmp_path: Path, invariants: Invariants, capsys: pytest.CaptureFixture[str]) -> None:
    sim = ModbusSimController()
    await sim.start()
    sentinel = {"offset": 7.25, "heartbeat": 99.0, "status": 5.0}
    await sim.publish(sentinel)  # what the controller held before the run
    doc = _recorder_doc(sim, tmp_path)
    path = tmp_path / "warmup.recorder.toml"
    path.write_text(tomltext.dumps(doc), encoding="utf-8")
    assert await asyncio.to_thread(cli, ["check", str(path)]) == 0
    out = capsys.readouterr().out
    assert "recorder only" in out and "writes nothing to the controller" in out
    cfg = parse_config(doc, path)
    assert cfg.recorder_only and not cfg.outputs and not cfg.states

    state = {"growth": 0.0}

    async def plant(index: int, t: float) -> None:
        bearing = 20.0 + 6.0 * (1.0 - math.exp(-t / 600.0)) if t < 1200.0 \
            else 20.0 + 6.0 * (1.0 - math.exp(-2.0)) * math.exp(-(t - 1200.0) / 600.0)
        a = math.exp(-1.0 / TAU_S)
        state["growth"] = a * state["growth"] + (1 - a) * GAIN_UM_K * (bearing - 20.0)
        await sim.publish({"bearing": bearing, "ambient": 20.0,
                           "growth_um": state["growth"]})
        if index == STALL_AT and not state.get("stalled"):  # inside the read, once: as a
            state["stalled"] = 1.0  # loaded machine stalls this process
            await asyncio.sleep(STALL_S)

    rig = DaemonRig(sim, cfg, invariants, plant, stepped=True)
    await rig.start()
    try:
        await rig.until(lambda: rig.daemon.loop.cycles >= 2400, limit_s=300.0)
        r = rig.daemon.loop.last_result
        assert r is not None and r.cause is Cause.RECORDER_ONLY and r.healthy
        assert r.writes == {} and r.model_um is None and r.record.complete
        assert await sim.outputs() == pytest.approx(sentinel)
        assert "recorder_only" in rig.log.names()
    finally:
        assert await rig.stop() == 0
        await sim.stop()
    assert not any(c.written for c in invariants.log())  # not one write was attempted
    assert not invariants.violations

    model = tmp_path / "plant.toml"
    assert await asyncio.to_thread(cli, [
        "fit", str(tmp_path / "calib.sqlite"), "--column", "growth_um",
        "--term", "bearing-ambient", "-o", str(model)]) == 0
    capsys.readouterr()
    # the reference the fit measured from (the record's first sample), said what it is
    text = model.read_text(encoding="utf-8")
    assert "The reference state: the temperatures of the calibration record's first" \
        " sample\n# (calib.sqlite)" in text
    assert tomllib.loads(text)["reference"] == {"ambient": 20.0, "bearing": 20.0}
    assert await asyncio.to_thread(cli, ["check", str(model), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    dc = report["terms"][0]["dc_gain"]
    assert dc == pytest.approx(GAIN_UM_K, rel=0.05)
