"""`compd health`: healthy only on evidence of a recent complete cycle, from a
real Prometheus endpoint or from the state directory; one line saying why."""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from prometheus_client import CollectorRegistry, Gauge

from compd.cli import main
from compd.commands import health
from compd.faces.telemetry import Metrics
from compd.runtime.checkpoint import save_checkpoint
from drivers.sim.ports import free_tcp_port


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
    rc, line = _health(capsys, "--url", _url(metrics))
    assert rc == 0
    assert line == "healthy: metrics: 3 cycles complete"


def test_endpoint_before_the_first_cycle_is_unhealthy(
        metrics: Metrics, capsys: pytest.CaptureFixture[str]) -> None:
    rc, line = _health(capsys, "--url", _url(metrics))
    assert rc == 1
    assert line.startswith("unhealthy: metrics ") and line.endswith("no complete cycle yet")


def test_stopped_fault_state_is_unhealthy(
        metrics: Metrics, capsys: pytest.CaptureFixture[str]) -> None:
    metrics.cycle_seconds.observe(0.002)
    metrics.fault_state.set(3)
    rc, line = _health(capsys, "--url", _url(metrics))
    assert rc == 1 and "fault state 3 (alarm/stopped)" in line
    metrics.fault_state.set(1)  # holding is still a working daemon
    assert _health(capsys, "--url", _url(metrics))[0] == 0


def test_last_cycle_timestamp_is_checked_when_exported(
        metrics: Metrics, capsys: pytest.CaptureFixture[str]) -> None:
    metrics.cycle_seconds.observe(0.002)
    last = Gauge("compd_last_cycle_timestamp_seconds", "wall time of the last complete cycle",
                 registry=metrics.registry)
    last.set(time.time() - 600.0)
    rc, line = _health(capsys, "--url", _url(metrics), "--max-age-s", "60")
    assert rc == 1 and "last complete cycle 600 s ago (max 60 s)" in line
    last.set_to_current_time()
    rc, line = _health(capsys, "--url", _url(metrics), "--max-age-s", "60")
    assert rc == 0 and "1 cycles, last 0 s ago" in line


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
    assert rc == 1 and "no compd_cycle_seconds_count" in line


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


def test_fresh_checkpoint_is_healthy(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    save_checkpoint(tmp_path / "checkpoint.json", {"offset_um": 1.5, "sequence": 9})
    rc, line = _health(capsys, "--state-dir", str(tmp_path), "--max-age-s", "60")
    assert rc == 0
    assert line.startswith("healthy: state dir: checkpoint saved ")


def test_old_checkpoint_and_old_record_are_unhealthy(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    old_s = time.time() - 1000.0
    (tmp_path / "checkpoint.json").write_text(json.dumps({"saved_wall_s": old_s}))
    record = tmp_path / "samples.sqlite-wal"
    record.write_bytes(b"x")
    os.utime(record, (old_s + 100.0, old_s + 100.0))
    rc, line = _health(capsys, "--state-dir", str(tmp_path), "--max-age-s", "120")
    assert rc == 1
    assert line == (f"unhealthy: state dir {tmp_path}: newest samples.sqlite-wal written "
                    "900 s ago (max 120 s)")


def test_a_fresh_record_counts_even_beside_a_torn_checkpoint(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "checkpoint.json").write_text('{"saved_wall_s": 17')  # torn
    (tmp_path / "samples.sqlite").write_bytes(b"")
    rc, line = _health(capsys, "--state-dir", str(tmp_path))
    assert rc == 0 and "samples.sqlite written" in line


def test_lock_and_temp_files_prove_nothing(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "compd.lock").write_text("123")
    (tmp_path / ".checkpoint.json.tmp").write_text("{}")
    rc, line = _health(capsys, "--state-dir", str(tmp_path))
    assert rc == 1 and line.endswith("no checkpoint or record yet")


def test_missing_state_dir_is_unhealthy(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc, line = _health(capsys, "--state-dir", str(tmp_path / "nope"))
    assert rc == 1 and line.endswith("not a directory")


def test_default_state_dir_comes_from_systemd(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("STATE_DIRECTORY", str(tmp_path))
    save_checkpoint(tmp_path / "checkpoint.json", {"sequence": 1})
    assert _health(capsys)[0] == 0


def test_either_source_suffices_and_both_are_named(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    save_checkpoint(tmp_path / "checkpoint.json", {"sequence": 1})
    url = f"http://127.0.0.1:{free_tcp_port('127.0.0.1')}/metrics"
    rc, line = _health(capsys, "--url", url, "--state-dir", str(tmp_path))
    assert rc == 0
    assert line.startswith(f"healthy: metrics {url}: ") and "; state dir: checkpoint" in line


def test_bad_max_age_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc, line = _health(capsys, "--state-dir", str(tmp_path), "--max-age-s", "nan")
    assert rc == 1 and "--max-age-s" in line


def test_health_imports_only_the_standard_library() -> None:
    code = ("import sys, compd.commands.health\n"
            "heavy = {'numpy', 'pydantic', 'prometheus_client', 'structlog', 'asyncua',\n"
            "         'pymodbus', 'snap7', 'scipy', 'models', 'drivers'}\n"
            "print(sorted(m for m in sys.modules if m.split('.')[0] in heavy))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, timeout=60).stdout
    assert out.strip() == "[]"


# -- against the real daemon -------------------------------------------------------------


async def test_running_daemon_is_healthy_by_both_sources(tmp_path: Path) -> None:
    from compd.config.loader import load_config
    from compd.runtime.daemon import Daemon
    from compd.runtime.sdnotify import Notifier
    from drivers.sim.modbus_server import ModbusSimController
    from tests.compd.daemon_helpers import write_config

    sim = ModbusSimController()
    await sim.start()
    try:
        await sim.publish({"bearing": 20.0, "ambient": 20.0})
        path = write_config(tmp_path, sim.endpoint, checkpoint_every=5)
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
            for _ in range(400):
                if daemon.complete_cycles >= 10:
                    break
                await asyncio.sleep(0.01)
            assert await asyncio.to_thread(health.run, args) == 0
            assert await asyncio.to_thread(health.run, state_args) == 0
        finally:
            daemon.request_stop()
            assert await task == 0
        # stopped: the endpoint is gone, the state dir is still fresh
        assert await asyncio.to_thread(health.run, args) == 1
    finally:
        await sim.stop()
