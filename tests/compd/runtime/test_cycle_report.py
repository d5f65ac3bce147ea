"""One cycle report, one meaning per name: every output of the daemon says, for
the same cycle, the value of the report's field it means.

A lockstep daemon (stepped clock, in-memory controller) runs 200 cycles whose
offset writes fail now and then (single failures and a run long enough for a
write fault). After each cycle a probe sink, fed last, reads what the metrics,
the status page and the OPC UA face's values say; at the end the recorder's
file and the checkpoint are read. Each must equal the report's field it is
documented to show: the stage's value, the value sent, the value the controller
confirmed, inputs valid, in force, and the cycle's time.
"""

from __future__ import annotations

import asyncio
import math
import sqlite3
from pathlib import Path
from typing import Any

import pytest
from prometheus_client import generate_latest

from compd.config.loader import LoadedConfig, load_config
from compd.core.plan import Row
from compd.faces.opcua_face import published_values
from compd.runtime.checkpoint import CHECKPOINT_NAME, load_checkpoint
from compd.runtime.daemon import Daemon
from compd.runtime.sinks.base import CycleSink, Tick
from drivers.errors import ControllerTimeout
from tests.configs import write_config
from tests.harness import memory_daemon

EPOCH = 1_700_000_000.0
CYCLES = 200


def _fails(k: int) -> bool:
    """Whether cycle k's write fails: one in seven, and a run of six (a write fault)."""
    return k % 7 == 3 or 120 <= k < 126


def _gauge(text: str, name: str) -> float:
    for line in text.splitlines():
        if line.startswith(name + " "):
            return float(line.split()[1])
    raise AssertionError(f"{name} not exported")


class _Probe(CycleSink):
    """Fed after every other sink: what each output says of this cycle."""

    stage = "probe"

    def __init__(self, daemon: Daemon) -> None:
        self.daemon = daemon
        self.seen: list[tuple[Row, dict[str, Any]]] = []

    def feed(self, tick: Tick) -> None:
        d = self.daemon
        text = generate_latest(d.metrics.registry).decode()
        page = dict(d.status_board.snapshot)
        face = published_values(tick.row, tick.cfg)
        self.seen.append((tick.row, {
            "metric_offset": _gauge(text, "compd_offset_micrometres"),
            "metric_confirmed": _gauge(text, "compd_offset_confirmed_micrometres"),
            "metric_complete": _gauge(text, "compd_cycles_complete_total"),
            "page": page, "face_offset": face["Offset_um"][0],
            "face_in_force": face["OffsetInForce"][0],
            "last_complete": d.checkpoint.last_complete, "mono_s": tick.mono_s}))


def _same(a: float | None, b: float | None) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return a == b or (math.isnan(a) and math.isnan(b))


async def _run(tmp_path: Path) -> tuple[LoadedConfig, _Probe]:
    path = write_config(tmp_path, "127.0.0.1:1", time_scale=1.0, timeout_s=0.4,
                        slew_um_s=0.5)
    path.write_text(path.read_text() + "\n[faces.http]\nenabled = true\n")
    cfg = load_config(path)
    daemon, clock, driver = memory_daemon(cfg, epoch=EPOCH)
    probe = _Probe(daemon)
    daemon.sinks.append(probe)
    task = asyncio.create_task(daemon.run())
    await clock.cycle_done(1)
    for k in range(1, CYCLES):
        driver.set("bearing", 20.0 + 0.08 * k)  # warming: the offset keeps moving
        if _fails(k):
            driver.fail_next_write = ControllerTimeout("write timed out", channel="offset")
        clock.tick()
        await clock.cycle_done(k + 1)
    daemon.request_stop()
    assert await task == 0
    return cfg, probe


async def test_every_output_reports_the_reports_named_value_for_the_same_cycle(
        tmp_path: Path) -> None:
    cfg, probe = await _run(tmp_path)
    reports = [row for row, _ in probe.seen]
    assert len(reports) == CYCLES + 1  # and the one the stop request ends after
    # the writes failed, so the names differ: the test has something to tell apart
    assert sum(not r.write_ok for r in reports) >= 30
    assert any(r.confirmed_um != r.stage_um for r in reports)
    assert any(r.inputs_valid and not r.in_force for r in reports)
    assert any(r.in_force for r in reports)
    complete = 0.0
    last_complete: tuple[float, float] | None = None
    for row, said in probe.seen:
        page = said["page"]
        # the output stage's value
        assert said["metric_offset"] == row.stage_um == page["offset_um"]
        # what the controller confirmed holding
        assert _same(said["metric_confirmed"],
                     math.nan if row.confirmed_um is None else row.confirmed_um)
        assert _same(page["confirmed_um"], row.confirmed_um)
        assert _same(said["face_offset"],
                     math.nan if row.confirmed_um is None else row.confirmed_um)
        # in force and inputs valid: one meaning each, on the page as in the counter
        assert page["complete"] is row.in_force and page["inputs_valid"] is row.inputs_valid
        complete += 1.0 if row.in_force else 0.0
        assert said["metric_complete"] == complete
        assert said["face_in_force"] is row.healthy
        # the cycle's time: read once, the same for the page and the checkpoint
        assert page["wall_s"] == row.wall_s == EPOCH + row.machine_s
        # the checkpoint notes a cycle after the sinks (the probe sees the one before)
        assert said["last_complete"] == last_complete
        if row.in_force:
            last_complete = (row.wall_s, said["mono_s"])
    # the recorder's file: its columns, each the report's field it is documented as
    conn = sqlite3.connect(tmp_path / "state" / "samples.sqlite")
    try:
        rows = conn.execute("SELECT cycle, mono_s, wall_s, offset_um, attempted_um, complete,"
                            " valid FROM samples ORDER BY seq").fetchall()
    finally:
        conn.close()
    assert len(rows) == len(reports)
    for report, (seq, mono_s, wall_s, offset_um, attempted_um, done, valid) in zip(
            reports, rows, strict=True):
        assert seq == report.sequence and mono_s == report.machine_s
        assert wall_s == report.wall_s
        assert attempted_um == pytest.approx(report.sent_um) if report.sent_um is not None \
            else attempted_um is None
        if report.write_ok and report.sent_um is not None:
            assert offset_um == pytest.approx(report.confirmed_um)
        else:
            assert offset_um is None
        assert bool(done) is report.in_force and bool(valid) is report.inputs_valid
    # the checkpoint: the offset confirmed and the last complete cycle, as reported
    doc = load_checkpoint(cfg.state_dir / CHECKPOINT_NAME)
    assert doc is not None
    assert doc["offset_um"] == pytest.approx(reports[-1].confirmed_um)
    assert last_complete is not None
    assert (doc["last_complete_wall_s"], doc["last_complete_mono_s"]) == last_complete
    assert doc["last_cause"] in {str(r.cause) for r in reports}
