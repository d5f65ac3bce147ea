"""The operator status page ([faces.http]): its data (state words, the recorder's
history thinned), / and /status.json of a running daemon against a simulated
controller, hostile requests, `compd status`, and the fleet's page."""

from __future__ import annotations

import argparse
import asyncio
import itertools
import json
import socket
import sqlite3
import time
from pathlib import Path
from typing import cast

import pytest
import structlog

from compd.commands import status as status_cmd
from compd.config.loader import LoadedConfig
from compd.core.faults import FaultState
from compd.core.health import Cause
from compd.core.plan import Row
from compd.core.record import RecordRow
from compd.faces.status import StatusBoard, operator_state, read_history
from compd.faces.status_page import render_page
from compd.faces.telemetry import Metrics
from compd.runtime.recorder import Recorder
from compd.sysexits import EX_DATAERR, EX_TEMPFAIL, EX_USAGE
from drivers.sim.modbus_server import ModbusSimController
from drivers.sim.ports import free_tcp_port
from tests.compd.faces.status_helpers import get, page_daemon, step

# -- the data ------------------------------------------------------------------------------


def test_every_fault_state_has_a_word_and_a_reason() -> None:
    # the word of each state for a cause that takes the state's word
    fault = {FaultState.OK: Cause.IN_FORCE, FaultState.INIT: Cause.INPUTS_INVALID,
             FaultState.HOLD: Cause.INPUTS_INVALID, FaultState.RAMP: Cause.INPUTS_INVALID,
             FaultState.SHUTDOWN: Cause.SHUTTING_DOWN, FaultState.STOPPED: Cause.WRITE_STOPPED,
             FaultState.HELD: Cause.FOREIGN_OFFSET_HELD, FaultState.WRITE_FAULT: Cause.WRITE_FAULT}
    words = {s: operator_state(s, fault[s], {})[0] for s in FaultState}
    assert words == {FaultState.OK: "on", FaultState.INIT: "holding",
                     FaultState.HOLD: "holding", FaultState.RAMP: "ramping",
                     FaultState.SHUTDOWN: "ramping", FaultState.STOPPED: "off",
                     FaultState.HELD: "off", FaultState.WRITE_FAULT: "off"}
    word, why = operator_state(FaultState.HOLD, Cause.INPUTS_INVALID,
                               {"bearing": "stale", "ambient": None})
    assert word == "holding" and "held" in why and "bearing: stale" in why
    assert "ambient" not in why
    assert operator_state(FaultState.OK, Cause.OPERATOR_HOLD, {})[0] == "holding"
    assert operator_state(FaultState.HOLD, Cause.INPUTS_INVALID, {})[0] == "holding"
    assert operator_state(FaultState.RAMP, Cause.INPUTS_INVALID, {})[0] == "ramping"
    assert operator_state(FaultState.HOLD, Cause.INPUTS_INVALID, {}, dry_run=True)[1].endswith(
        "dry run: nothing is written")


def test_every_cause_has_its_own_reason() -> None:
    """Each cause is said as it is: no two causes share a reason, and one that is
    not about the inputs never says they are invalid (a model worse than none
    was once shown as "holding - inputs invalid")."""
    state = {Cause.IN_FORCE: FaultState.OK, Cause.OPERATOR_HOLD: FaultState.OK,
             Cause.AT_LIMIT: FaultState.OK, Cause.FOREIGN_OFFSET: FaultState.OK,
             Cause.NO_READBACK: FaultState.OK, Cause.WRITE_FAILED: FaultState.OK,
             Cause.SHUTTING_DOWN: FaultState.SHUTDOWN, Cause.WRITE_STOPPED: FaultState.STOPPED,
             Cause.FOREIGN_OFFSET_HELD: FaultState.HELD, Cause.WRITE_FAULT: FaultState.WRITE_FAULT,
             Cause.CONTROLLER_OFF: FaultState.HOLD}
    whys = {c: operator_state(state.get(c, FaultState.HOLD), c, {"bearing": None})[1]
            for c in Cause}
    assert len(set(whys.values())) == len(Cause)
    for cause, why in whys.items():
        assert ("inputs invalid" in why) == (cause is Cause.INPUTS_INVALID), (cause, why)
    word, why = operator_state(FaultState.RAMP, Cause.MODEL_WORSE_THAN_NONE, {"bearing": None})
    assert word == "ramping" and "worse than none" in why and "ramps to 0" in why
    assert operator_state(FaultState.OK, Cause.AT_LIMIT, {})[0] == "limited"


def _recorder_with(path: Path, n: int, now: float, step_s: float = 1.0) -> None:
    rec = Recorder(path, commit_every=1000)
    rec.open()
    for i in range(n):
        wall = now - (n - 1 - i) * step_s
        rec.record(RecordRow(seq=i, mono_s=float(i), wall_s=wall, offset_um=i / 10.0,
                             model_um=None if i % 7 == 0 else i / 10.0 + 0.5, state="ok",
                             valid=True))
    rec.close()


def test_history_is_thinned_to_the_bound_and_keeps_the_newest_sample(tmp_path: Path) -> None:
    now = 2_000_000_000.0
    path = tmp_path / "samples.sqlite"
    _recorder_with(path, 5000, now)
    h = read_history(path, hours=1.0, max_points=100, now_wall_s=now)
    t = h["wall_s"]
    assert "error" not in h
    assert 90 <= len(t) <= 100
    assert t[-1] == now  # the newest sample is always shown
    assert t[0] >= now - 3600.0  # nothing older than the window
    steps = {round(b - a, 6) for a, b in itertools.pairwise(t)}
    assert len(steps) == 1  # evenly spaced
    assert h["offset_um"][-1] == pytest.approx(499.9)
    # model_um NULL (the model did not step) stays a gap, not a zero
    for offset, model in zip(h["offset_um"], h["model_um"], strict=True):
        assert (model is None) == (round(offset * 10) % 7 == 0)
    # a window shorter than the recording, and a bound above it: every row
    small = read_history(path, hours=50.0 / 3600.0, max_points=1000, now_wall_s=now)
    assert len(small["wall_s"]) == 51


def test_history_says_why_it_is_empty(tmp_path: Path) -> None:
    assert read_history(None, 1.0)["error"] == "no recorder configured"
    assert read_history(tmp_path / "none.sqlite", 1.0)["error"] == "no recorder file yet"
    garbage = tmp_path / "garbage.sqlite"
    garbage.write_bytes(b"not a database" * 100)
    assert read_history(garbage, 1.0)["error"].startswith("recorder unreadable")
    old = tmp_path / "old.sqlite"
    _recorder_with(old, 10, 1_000_000_000.0)
    h = read_history(old, 1.0, now_wall_s=2_000_000_000.0)
    assert h["wall_s"] == [] and "no samples" in h["error"]


def test_a_locked_recorder_answers_an_error_after_a_bounded_wait(tmp_path: Path) -> None:
    path = tmp_path / "samples.sqlite"
    now = time.time()
    _recorder_with(path, 100, now)
    holder = sqlite3.connect(path, isolation_level=None)
    try:
        holder.execute("PRAGMA locking_mode=EXCLUSIVE")
        holder.execute("BEGIN EXCLUSIVE")
        holder.execute("DELETE FROM meta WHERE key = 'none'")
        h = read_history(path, 1.0, now_wall_s=now)
    finally:
        holder.close()
    assert h["wall_s"] == [] and h["error"].startswith("recorder unreadable")
    assert len(read_history(path, 1.0, now_wall_s=now)["wall_s"]) == 100  # free again


def test_a_snapshot_that_cannot_be_built_keeps_the_last_one() -> None:
    board = StatusBoard()
    first = board.snapshot
    # neither a committed row nor a config: the snapshot cannot be built from them
    not_a_row, not_a_config = cast(Row, object()), cast(LoadedConfig, object())
    with structlog.testing.capture_logs() as logs:
        board.publish(not_a_row, not_a_config)
        board.publish(not_a_row, not_a_config)
    assert board.snapshot is first
    assert [e["event"] for e in logs] == ["status_snapshot_failed"]  # once, not per cycle


def test_the_page_has_no_external_asset_and_cannot_be_broken_out_of() -> None:
    page = render_page({"machine": "</script><script>alert(1)</script>", "state": "on",
                        "channels": []}, 5.0)
    assert "<script>alert(1)" not in page and "&lt;/script&gt;" in page
    for outside in ("src=", "<link", "http://", "https://", "@import", "url("):
        assert outside not in page


# -- a running daemon -------------------------------------------------------------------


async def test_page_and_status_json_follow_the_daemon(
        sim: ModbusSimController, tmp_path: Path) -> None:
    async with page_daemon(tmp_path, sim, stepped=True) as (daemon, base):
        await step(daemon, 10)  # the recorder commits every 10
        assert daemon.telemetry.complete_cycles == 13
        code, ctype, body = await asyncio.to_thread(get, base)
        assert code == 200 and ctype.startswith("text/html")
        assert b'"state": "on"' in body and b'getContext("2d")' in body  # inline plot
        code, ctype, body = await asyncio.to_thread(get, base + "status.json")
        doc = json.loads(body)
        assert code == 200 and ctype == "application/json"
        assert (doc["machine"], doc["state"], doc["limit_um"]) == ("test", "on", 100.0)
        assert [(c["name"], c["value"], c["valid"]) for c in doc["channels"]] == [
            ("bearing", 20.0, True), ("ambient", 20.0, True)]
        assert doc["history"]["wall_s"] and doc["refresh_s"] == 1.0
        assert doc["period_s"] == pytest.approx(1.0) and 0.0 <= doc["age_s"] < 60.0
        assert await asyncio.to_thread(status_cmd.run, _args(base)) == 0
        # a fault: the bearing reads out of range; the page says holding, and why
        await sim.publish({"bearing": 500.0, "ambient": 20.0})
        await step(daemon)
        doc = json.loads((await asyncio.to_thread(get, base + "status.json"))[2])
        assert doc["state"] == "holding" and "bearing: out_of_range" in doc["why"]
        assert doc["channels"][0]["valid"] is False
        assert "channel_invalid" in [a["event"] for a in doc["alarms"]]
        assert await asyncio.to_thread(status_cmd.run, _args(base)) == 1
        code, _, body = await asyncio.to_thread(get, base + "metrics")
        assert code == 200 and b"compd_cycles_complete_total" in body


async def test_hostile_requests_are_refused_and_the_cycle_runs_on(
        sim: ModbusSimController, tmp_path: Path) -> None:
    async with page_daemon(tmp_path, sim, stepped=True) as (daemon, base):
        assert (await asyncio.to_thread(get, base + "nope"))[0] == 404
        assert (await asyncio.to_thread(get, base + "favicon.ico"))[0] == 404
        for path in ("", "status.json", "metrics"):
            code, _, _ = await asyncio.to_thread(get, base + path, "POST")
            assert code == 405, path
        assert (await asyncio.to_thread(get, base + "status.json", "DELETE"))[0] == 405
        code, _, body = await asyncio.to_thread(get, base + "status.json", "HEAD")
        assert code == 200 and body == b""
        code, _, body = await asyncio.to_thread(get, base + "status.json?" + "x" * 8000)
        assert code == 200 and json.loads(body)["state"] == "on"  # the query is ignored
        assert (await asyncio.to_thread(get, base + "?" + "x" * 70_000))[0] == 414
        # a client that connects and says nothing holds one thread, nothing else
        port = int(base.rsplit(":", 1)[1].strip("/"))
        with socket.create_connection(("127.0.0.1", port), timeout=5.0) as silent:
            silent.sendall(b"GET /status.json HTTP/1.1\r\n")
            before = daemon.telemetry.complete_cycles
            await step(daemon, 5)  # the loop is not held up: every cycle runs
            assert daemon.telemetry.complete_cycles == before + 5
            assert (await asyncio.to_thread(get, base + "status.json"))[0] == 200


async def test_without_a_recorder_the_page_says_so(
        sim: ModbusSimController, tmp_path: Path) -> None:
    async with page_daemon(tmp_path, sim, recorder=False, stepped=True) as (_daemon, base):
        doc = json.loads((await asyncio.to_thread(get, base + "status.json"))[2])
    assert doc["state"] == "on"
    assert doc["history"]["wall_s"] == [] and doc["history"]["error"] == "no recorder configured"


def test_a_reload_that_changes_the_page_restarts_the_server(tmp_path: Path) -> None:
    from compd.config.loader import load_config
    from compd.runtime.reload import diff
    from tests.configs import write_config

    path = write_config(tmp_path, "modbus://127.0.0.1:1502")
    old = load_config(path)
    path.write_text(path.read_text() + "\n[faces.http]\nenabled = true\n")
    assert diff(old, load_config(path)).metrics
    assert not diff(old, old).metrics


# -- compd status -----------------------------------------------------------------------


def _args(url: str, *, as_json: bool = False) -> argparse.Namespace:
    return argparse.Namespace(url=url, json=as_json, timeout_s=30.0)  # a loaded machine


def test_status_says_one_line_for_a_bad_url_or_an_unreachable_page(
        capsys: pytest.CaptureFixture[str]) -> None:
    for url in ("ftp://127.0.0.1/", "http://", "http://127.0.0.1:99999/", "not a url"):
        assert status_cmd.run(_args(url)) == EX_USAGE, url
    dead = free_tcp_port("127.0.0.1")
    assert status_cmd.run(_args(f"http://127.0.0.1:{dead}/")) == EX_TEMPFAIL
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 5 and all(line.startswith("compd status: ") for line in err)
    assert "Traceback" not in "".join(err)


def test_status_refuses_what_is_not_a_status_document(
        capsys: pytest.CaptureFixture[str]) -> None:
    metrics = Metrics()  # a plain metrics server: /status.json answers Prometheus text
    metrics.start_http(0)
    try:
        assert status_cmd.run(_args(f"http://127.0.0.1:{metrics.port}/")) == EX_DATAERR
    finally:
        metrics.stop()
    assert "not JSON" in capsys.readouterr().err


async def test_status_json_and_a_missing_page(sim: ModbusSimController, tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    async with page_daemon(tmp_path, sim) as (_daemon, base):
        assert await asyncio.to_thread(status_cmd.run, _args(base, as_json=True)) == 0
        out = capsys.readouterr().out  # structlog's default printer may share stdout
        doc = json.loads(out[out.index("{\n"):])
        assert doc["machine"] == "test" and doc["state"] == "on"
        assert await asyncio.to_thread(status_cmd.run, _args(base + "nope")) == EX_TEMPFAIL
        assert "HTTP 404 (is [faces.http] enabled?)" in capsys.readouterr().err


def test_one_line_per_machine() -> None:
    line = status_cmd.describe({"machine": "mill-a", "state": "holding", "why": "inputs invalid",
                                "offset_um": 12.345, "limit_um": 100.0, "model_um": None,
                                "channels": [{"valid": True}, {"valid": False}]})
    assert line == ("mill-a: holding - inputs invalid; offset 12.35 um (limit +-100 um), "
                    "model -, channels 1/2 valid")
    stalled = status_cmd.describe({"machine": "mill-b", "state": "on", "why": "",
                                   "age_s": 100.0, "period_s": 1.0, "channels": []})
    assert stalled.endswith("; NO CYCLE FOR 100 s")
    assert not status_cmd.stalled({"state": "on", "age_s": 4.0, "period_s": 1.0})


# -- compd run DIR: one page for every machine -------------------------------------------


async def test_a_fleet_page_lists_every_machine(tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    from compd.runtime.fleet import Fleet, load_machines
    from compd.testing import SteppedClock
    from tests.configs import write_config
    from tests.harness import Fleetstep

    sims = [ModbusSimController() for _ in range(2)]
    port = free_tcp_port("127.0.0.1")
    machines = tmp_path / "machines.d"
    machines.mkdir()
    for name, sim in zip(("mill-a", "mill-b"), sims, strict=True):
        await sim.start()
        await sim.publish({"bearing": 20.0, "ambient": 20.0})
        # in lockstep (one stepped clock for both machines): machine seconds, and a
        # request may take half a period of real time
        write_config(machines, sim.endpoint, filename=f"{name}.toml", name=name,
                     dir=f"state-{name}", time_scale=1.0, timeout_s=0.5,
                     swap=[("[telemetry]", f"[telemetry]\nmetrics_port = {port}")],
                     extra="\n[faces.http]\nenabled = true\n")
    clock = SteppedClock(period_s=1.0)
    fleet = Fleet(load_machines(machines), clock=clock, sleep=clock.sleep)
    task = asyncio.get_running_loop().create_task(fleet.run())
    fs = Fleetstep(clock, task)
    base = f"http://127.0.0.1:{port}/"
    try:
        await fs.until_asleep(2)  # both machines ran their first cycle
        await fs.step(2)
        assert [d.telemetry.complete_cycles for d in fleet.daemons.values()] == [3, 3]
        await sims[1].publish({"bearing": 500.0, "ambient": 20.0})
        await fs.step()
        assert fleet.daemons["mill-b"].status_board.snapshot["state"] == "holding"
        doc = json.loads((await asyncio.to_thread(get, base + "status.json"))[2])
        assert [(m["machine"], m["state"]) for m in doc["machines"]] == [
            ("mill-a", "on"), ("mill-b", "holding")]
        code, _, page = await asyncio.to_thread(get, base)
        assert code == 200 and b"2 machines" in page and b"mill-b" in page
        assert await asyncio.to_thread(status_cmd.run, _args(base)) == 1  # one is not on
        lines = [x for x in capsys.readouterr().out.splitlines() if x.startswith("mill-")]
        assert [x.split(":")[0] for x in lines] == ["mill-a", "mill-b"]
        assert (await asyncio.to_thread(get, base + "metrics"))[0] == 200
    finally:
        fleet.request_stop()
        await asyncio.wait_for(task, 120.0)
        for sim in sims:
            await sim.stop()


# -- the model's start, its reference and a change waiting for permission --------------


def test_the_page_and_compd_status_say_the_pending_change_the_start_and_the_reference(
        tmp_path: Path) -> None:
    from compd.config.loader import load_config
    from compd.core.cycle import Cycle, params_from_config
    from tests.compd.core.cycle_helpers import samples
    from tests.configs import write_config

    cfg = load_config(write_config(tmp_path, "modbus://127.0.0.1:5020"))
    cycle = Cycle(params_from_config(cfg), cfg.model)
    board = StatusBoard()
    controller, t = 0.0, 0.0
    for k in range(40):
        t += 1.0
        bearing = 20.0 if k < 30 else 20.0 + 0.4 * (k - 29)  # warms while not permitted
        cycle.plan(t, samples(t, bearing), controller, permitted=k < 30)
        row = cycle.commit()
        controller = row.writes.get("offset", controller)
    board.publish(row, cfg)
    doc = board.snapshot
    assert doc["cause"] == "waiting_for_permission" and doc["state"] == "waiting"
    assert doc["pending_um"] is not None and doc["pending_um"] > 1.0
    assert f"({doc['pending_um']:+.3f} um pending)" in doc["why"]
    assert doc["model_start"] == "first_start"
    assert doc["reference"] == {"source": "first_sample",
                                "temperatures_c": {"ambient": 20.0, "bearing": 20.0}}
    assert doc["recorder_only"] is False and doc["zero_um"] is None
    line = status_cmd.describe({**doc, "age_s": 0.0})
    assert "um pending" in line and "started first_start" in line
    assert "reference (first_sample) ambient 20, bearing 20 C" in line
    json.dumps(doc, allow_nan=False)  # the page's JSON as served
    page = render_page(doc, 5.0)
    assert "m.pending_um" in page and "m.model_start" in page and "m.reference" in page


def test_every_cause_has_a_reason_on_the_page() -> None:
    """A cause the page had no words for (waiting for permission, an unreadable permit,
    recorder only) made every snapshot fail: the page froze at the last one."""
    for cause in Cause:
        word, why = operator_state(FaultState.OK, cause, {})
        assert word and why, cause
    assert operator_state(FaultState.OK, Cause.RECORDER_ONLY, {})[0] == "recording"


def test_the_page_says_the_offset_sent_and_the_one_the_controller_holds(
        tmp_path: Path) -> None:
    """A failed write: the stage's value (``offset_um``, sent) moved on, the controller
    still holds the last confirmed offset (``confirmed_um``), which the page says beside
    it; its history (the recorder's) is the confirmed one and its legend says so."""
    from compd.config.loader import load_config
    from compd.core.cycle import Cycle, params_from_config
    from compd.core.plan import Outcome
    from tests.compd.core.cycle_helpers import samples
    from tests.configs import write_config

    cfg = load_config(write_config(tmp_path, "modbus://127.0.0.1:5020"))
    cycle = Cycle(params_from_config(cfg), cfg.model)
    board = StatusBoard()
    controller, t = 0.0, 0.0  # what the controller holds, as read back
    for k in range(20):
        t += 1.0
        cycle.plan(t, samples(t, 20.0 + 0.4 * k), controller)
        row = cycle.commit()
        controller = row.writes.get("offset", controller)
    held = row.confirmed_um
    t += 1.0
    cycle.plan(t, samples(t, 28.0), controller)
    row = cycle.commit(Outcome.failed("offset", reason="timed out"))
    board.publish(row, cfg)
    doc = board.snapshot
    assert held is not None and doc["confirmed_um"] == pytest.approx(held)
    assert doc["offset_um"] == pytest.approx(row.stage_um)
    assert doc["offset_um"] != doc["confirmed_um"]
    page = render_page(doc, 5.0)
    assert "m.confirmed_um" in page and "offset confirmed" in page
    assert "offset written" not in page
