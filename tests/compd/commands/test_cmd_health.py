"""`compd health`: healthy only on evidence of a recent complete cycle, from a
real Prometheus endpoint or from the state directory; one line saying why."""

from __future__ import annotations

import argparse
import asyncio
import subprocess
import sys
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest
from prometheus_client import CollectorRegistry, Gauge

from compd.cli import main
from compd.commands import health
from compd.core.health import Cause
from compd.faces.telemetry import Metrics
from compd.runtime.checkpoint import save_checkpoint
from compd.runtime.liveness import boot_id
from drivers.sim.ports import free_tcp_port
from tests.harness import healthy_within, until


def _health(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str]:
    rc = main(["health", *argv])
    out = capsys.readouterr().out
    lines = out.splitlines()
    assert len(lines) == 1, out
    return rc, lines[0]


@pytest.fixture
def metrics() -> Iterator[Metrics]:
    m = Metrics()
    m.start_http(0)
    try:
        yield m
    finally:
        m.stop()


def _url(m: Metrics) -> str:
    return f"http://127.0.0.1:{m.port}/metrics"


# -- metrics endpoint -------------------------------------------------------------------


def test_endpoint_with_complete_cycles_is_healthy(
        metrics: Metrics, capsys: pytest.CaptureFixture[str]) -> None:
    for _ in range(3):
        metrics.cycle_seconds.observe(0.002)
        metrics.cycle_complete()
    rc, line = _health(capsys, "--url", _url(metrics))
    assert rc == 0
    assert line == "healthy: metrics: 3 complete cycles, last 0 s ago"


def test_endpoint_before_the_first_cycle_is_unhealthy(
        metrics: Metrics, capsys: pytest.CaptureFixture[str]) -> None:
    rc, line = _health(capsys, "--url", _url(metrics))
    assert rc == 1
    assert line.startswith("unhealthy: metrics ") and line.endswith("no complete cycle yet")


def test_cycles_that_ran_without_completing_prove_nothing(
        metrics: Metrics, capsys: pytest.CaptureFixture[str]) -> None:
    """No controller: 57 cycles ran (and were timed), none complete."""
    for _ in range(57):
        metrics.cycle_seconds.observe(0.5)
    rc, line = _health(capsys, "--url", _url(metrics))
    assert rc == 1 and line.endswith("no complete cycle yet")


def test_stopped_fault_state_is_unhealthy(
        metrics: Metrics, capsys: pytest.CaptureFixture[str]) -> None:
    metrics.cycle_complete()
    metrics.fault_state.set(3)
    rc, line = _health(capsys, "--url", _url(metrics))
    assert rc == 1 and "fault state 3 (alarm/stopped)" in line
    metrics.fault_state.set(1)  # not the alarm: whether it is in force is the cause's
    assert _health(capsys, "--url", _url(metrics))[0] == 0


@pytest.mark.parametrize("cause", list(Cause))
def test_every_cause_but_in_force_and_an_operator_hold_is_unhealthy_and_named(
        metrics: Metrics, capsys: pytest.CaptureFixture[str], cause: Cause) -> None:
    """A model worse than none held and ramping (fault state 1, then 2) once passed
    as healthy: the last complete cycle was recent. The cause says it is not."""
    metrics.cycle_complete()
    metrics.fault_state.set(2)
    metrics.cause(cause)
    rc, line = _health(capsys, "--url", _url(metrics))
    if cause in (Cause.IN_FORCE, Cause.OPERATOR_HOLD, Cause.WAITING_FOR_PERMISSION,
                 Cause.RECORDER_ONLY, Cause.DEGRADED):
        assert rc == 0, line
    else:
        assert rc == 1 and line.endswith(
            f"the offset compd wants is not in force ({cause})"), line


def test_a_stalled_loop_is_unhealthy_by_the_monotonic_age(
        metrics: Metrics, capsys: pytest.CaptureFixture[str]) -> None:
    metrics.cycle_complete()
    metrics._last_complete_mono = time.monotonic() - 600.0  # the loop stalled 10 min ago
    metrics.last_complete_timestamp.set(time.time() + 3600.0)  # and the wall clock jumped
    rc, line = _health(capsys, "--url", _url(metrics), "--max-age-s", "60")
    assert rc == 1 and "last complete cycle 600 s ago (max 60 s)" in line
    metrics.cycle_complete()
    rc, line = _health(capsys, "--url", _url(metrics), "--max-age-s", "60")
    assert rc == 0 and "2 complete cycles, last 0 s ago" in line


def test_nothing_listening_is_unhealthy(capsys: pytest.CaptureFixture[str]) -> None:
    url = f"http://127.0.0.1:{free_tcp_port('127.0.0.1')}/metrics"
    rc, line = _health(capsys, "--url", url, "--timeout-s", "2")
    assert rc == 1 and line.startswith(f"unhealthy: metrics {url}: ")
    assert "refused" in line.lower()


def test_an_endpoint_that_is_not_compd_is_unhealthy(capsys: pytest.CaptureFixture[str]) -> None:
    from prometheus_client import start_http_server

    other = CollectorRegistry()
    Gauge("something_else", "not compd", registry=other).set(1)
    server, thread = start_http_server(0, addr="127.0.0.1", registry=other)
    try:
        url = f"http://127.0.0.1:{server.server_address[1]}/metrics"
        rc, line = _health(capsys, "--url", url)
    finally:
        server.shutdown()
        server.server_close()
        thread.join(5.0)
    assert rc == 1 and "no compd_cycles_complete_total" in line


def test_parse_metrics_sums_labels_and_skips_comments() -> None:
    text = ("# HELP x y\n# TYPE x counter\n"
            'compd_read_errors_total{channel="a"} 2.0\n'
            'compd_read_errors_total{channel="b b}"} 3.0\n'
            "compd_cycle_seconds_count 7.0 1700000000000\n"
            "garbage line\n")
    parsed = health.parse_metrics(text)
    assert parsed["compd_read_errors_total"] == 5.0
    assert parsed["compd_cycle_seconds_count"] == 7.0


# -- state directory ---------------------------------------------------------------------


def _stamp(**extra: object) -> dict[str, object]:
    """Checkpoint keys of a cycle that completed just now, on this boot."""
    return {"last_complete_wall_s": time.time(), "last_complete_mono_s": time.monotonic(),
            "boot_id": boot_id(), **extra}


def test_fresh_complete_cycle_is_healthy(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    save_checkpoint(tmp_path / "checkpoint.json", {"offset_um": 1.5, "sequence": 9, **_stamp()})
    rc, line = _health(capsys, "--state-dir", str(tmp_path), "--max-age-s", "60")
    assert rc == 0
    assert line == "healthy: state dir: last complete cycle 0 s ago (monotonic clock)"


def test_a_checkpoint_whose_cause_is_not_in_force_is_unhealthy(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    save_checkpoint(tmp_path / "checkpoint.json", {
        "offset_um": 1.5, "sequence": 9, "last_state": "ramp",
        "last_cause": "model_worse_than_none", **_stamp()})
    rc, line = _health(capsys, "--state-dir", str(tmp_path), "--max-age-s", "60")
    assert rc == 1 and line.endswith("not in force (model_worse_than_none)"), line
    save_checkpoint(tmp_path / "checkpoint.json", {
        "offset_um": 1.5, "sequence": 10, "last_state": "ok", "last_cause": "operator_hold",
        **_stamp()})
    assert _health(capsys, "--state-dir", str(tmp_path), "--max-age-s", "60")[0] == 0


def test_checkpoint_of_a_daemon_that_never_completed_is_unhealthy(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Saved a second ago by a daemon with no controller: no evidence of a cycle."""
    save_checkpoint(tmp_path / "checkpoint.json", {"offset_um": 0.0, "sequence": 57})
    (tmp_path / "samples.sqlite-wal").write_bytes(b"x")  # the recorder wrote: proves nothing
    rc, line = _health(capsys, "--state-dir", str(tmp_path))
    assert rc == 1 and line.endswith("no complete cycle recorded")


def test_old_complete_cycle_is_unhealthy_even_with_a_fresh_record(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    stamp = _stamp(last_complete_mono_s=time.monotonic() - 900.0,
                   last_complete_wall_s=time.time() - 900.0)
    save_checkpoint(tmp_path / "checkpoint.json", stamp)
    (tmp_path / "samples.sqlite-wal").write_bytes(b"x")
    rc, line = _health(capsys, "--state-dir", str(tmp_path), "--max-age-s", "120")
    assert rc == 1
    assert line == (f"unhealthy: state dir {tmp_path}: last complete cycle 900 s ago "
                    "(max 120 s)")


def test_a_stamp_in_the_future_is_no_evidence(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Another boot (the monotonic clock is not comparable) and a wall stamp a day
    ahead: a clock stepped back. Neither reads healthy (it would, forever)."""
    stamp = _stamp(boot_id="another-boot", last_complete_wall_s=time.time() + 86400.0)
    save_checkpoint(tmp_path / "checkpoint.json", stamp)
    rc, line = _health(capsys, "--state-dir", str(tmp_path))
    assert rc == 1 and "in the future" in line
    # the same boot judges by the monotonic clock whatever the wall clock says
    save_checkpoint(tmp_path / "checkpoint.json",
                    _stamp(last_complete_wall_s=time.time() + 86400.0))
    assert _health(capsys, "--state-dir", str(tmp_path))[0] == 0


def test_torn_checkpoint_lock_and_temp_files_prove_nothing(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "compd.lock").write_text("123")
    (tmp_path / ".checkpoint.json.tmp").write_text("{}")
    rc, line = _health(capsys, "--state-dir", str(tmp_path))
    assert rc == 1 and line.endswith("no checkpoint yet")
    (tmp_path / "checkpoint.json").write_text('{"last_complete_wall_s": 17')  # torn
    rc, line = _health(capsys, "--state-dir", str(tmp_path))
    assert rc == 1 and "checkpoint unreadable" in line


def test_missing_state_dir_is_unhealthy(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc, line = _health(capsys, "--state-dir", str(tmp_path / "nope"))
    assert rc == 1 and line.endswith("not a directory")


def test_default_state_dir_comes_from_systemd(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("STATE_DIRECTORY", str(tmp_path))
    save_checkpoint(tmp_path / "checkpoint.json", {"sequence": 1, **_stamp()})
    assert _health(capsys)[0] == 0


def test_either_source_suffices_and_both_are_named(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    save_checkpoint(tmp_path / "checkpoint.json", {"sequence": 1, **_stamp()})
    url = f"http://127.0.0.1:{free_tcp_port('127.0.0.1')}/metrics"
    rc, line = _health(capsys, "--url", url, "--state-dir", str(tmp_path))
    assert rc == 0
    assert line.startswith(f"healthy: metrics {url}: ") and "; state dir: last complete" in line


@pytest.mark.parametrize(("option", "value"), [
    ("--max-age-s", "nan"), ("--max-age-s", "-1"), ("--max-age-s", "1e308"),
    ("--timeout-s", "1e308"), ("--timeout-s", "0"), ("--timeout-s", "inf")])
def test_bad_numbers_are_a_usage_error(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                       option: str, value: str) -> None:
    rc = main(["health", "--state-dir", str(tmp_path), option, value])
    out = capsys.readouterr()
    assert rc == 64 and out.out == ""
    assert out.err.count("\n") == 1 and option in out.err


def test_health_imports_only_the_standard_library() -> None:
    code = ("import sys, compd.commands.health\n"
            "heavy = {'numpy', 'pydantic', 'prometheus_client', 'structlog', 'asyncua',\n"
            "         'pymodbus', 'snap7', 'scipy', 'models', 'drivers'}\n"
            # the endpoint parser that redacts URLs and the JSON reader the checkpoint
            # reader bounds are standard library only themselves
            "light = {'drivers', 'drivers.endpoint', 'drivers.protocols',\n"
            "         'models', 'models.nesting'}\n"
            "print(sorted(m for m in sys.modules if m.split('.')[0] in heavy\n"
            "             and m not in light))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, timeout=60).stdout
    assert out.strip() == "[]"


# -- against the real daemon -------------------------------------------------------------


async def test_running_daemon_is_healthy_by_both_sources(tmp_path: Path) -> None:
    """In real time: the state dir's evidence is the checkpoint's monotonic stamp, judged
    on this host's monotonic clock (a stepped clock's would be no evidence). Time scale
    1, so a request has 0.4 s, which a loaded machine meets (at the sim's default 8 ms
    a write may time out and make that instant rightly unhealthy); a checkpoint every 2
    cycles, so that three cycles make both sources' evidence."""
    from compd.config.loader import load_config
    from compd.runtime.daemon import Daemon
    from compd.runtime.sdnotify import Notifier
    from drivers.sim.modbus_server import ModbusSimController
    from tests.configs import write_config

    sim = ModbusSimController()
    await sim.start()
    try:
        await sim.publish({"bearing": 20.0, "ambient": 20.0})
        path = write_config(tmp_path, sim.endpoint, checkpoint_every=2, time_scale=1.0)
        port = free_tcp_port("127.0.0.1")
        path.write_text(path.read_text() + f"metrics_port = {port}\n")
        cfg = load_config(path)
        daemon = Daemon(cfg, notifier=Notifier(None))
        task = asyncio.create_task(daemon.run())
        args = argparse.Namespace(url=f"http://127.0.0.1:{port}/metrics",
                                  state_dir=None, max_age_s=60.0, timeout_s=2.0)
        state_args = argparse.Namespace(url=None, state_dir=cfg.state_dir, max_age_s=60.0,
                                        timeout_s=2.0)
        try:
            def cycles() -> int:
                return daemon.telemetry.complete_cycles
            await until(lambda: cycles() >= 3, task=task)
            # a request slower than even 0.4 s makes one instant unhealthy: asked
            # again after the next complete cycle
            assert await healthy_within(lambda: health.run(args), cycles) == 0
            assert await healthy_within(lambda: health.run(state_args), cycles) == 0
        finally:
            daemon.request_stop()
            assert await task == 0
        # stopped: the endpoint is gone, the state dir is still fresh
        assert await asyncio.to_thread(health.run, args) == 1
    finally:
        await sim.stop()


async def test_daemon_without_a_controller_is_unhealthy_by_both_sources(
        tmp_path: Path) -> None:
    """Nothing listens: cycles run, checkpoints and records are written, and yet
    no cycle completed (it read 'healthy' and '57 cycles complete' once)."""
    from compd.config.loader import load_config
    from compd.runtime.daemon import Daemon
    from compd.runtime.sdnotify import Notifier
    from tests.configs import write_config

    dead = free_tcp_port("127.0.0.1")
    path = write_config(tmp_path, f"modbus://127.0.0.1:{dead}", checkpoint_every=2)
    port = free_tcp_port("127.0.0.1")
    path.write_text(path.read_text() + f"metrics_port = {port}\n")
    cfg = load_config(path)
    daemon = Daemon(cfg, notifier=Notifier(None))
    task = asyncio.create_task(daemon.run())
    url = f"http://127.0.0.1:{port}/metrics"
    args = argparse.Namespace(url=url, state_dir=None, max_age_s=60.0, timeout_s=2.0)
    state_args = argparse.Namespace(url=None, state_dir=cfg.state_dir, max_age_s=60.0,
                                    timeout_s=2.0)
    try:
        await until(lambda: daemon.loop.cycles >= 12, task=task)
        assert daemon.telemetry.complete_cycles == 0
        assert (cfg.state_dir / "checkpoint.json").exists()
        assert await asyncio.to_thread(health.run, args) == 1
        assert await asyncio.to_thread(health.run, state_args) == 1
        body = await asyncio.to_thread(
            lambda: urllib.request.urlopen(url, timeout=2.0).read().decode())
        assert health.parse_metrics(body)["compd_fault_state"] >= 1  # not "ok"
    finally:
        daemon.request_stop()
        assert await task == 0


def test_degraded_is_healthy_with_a_warning_naming_the_sensor(
        metrics: Metrics, capsys: pytest.CaptureFixture[str]) -> None:
    """A fallback model in force compensates from valid inputs: healthy (exit 0),
    and the line says which sensor is lost."""
    metrics.cycle_complete()
    metrics.fault_state.set(0)
    metrics.cause(Cause.DEGRADED)
    metrics.fallback("ambient")
    rc, line = _health(capsys, "--url", _url(metrics))
    assert rc == 0 and "warning: degraded, fallback model without ambient in force" in line
    metrics.fallback(None)
    metrics.cause(Cause.IN_FORCE)
    rc, line = _health(capsys, "--url", _url(metrics))
    assert rc == 0 and "degraded" not in line
