"""compd as a systemd service: the journal's priority prefix, the protocol
libraries' log level, $STATE_DIRECTORY / $CREDENTIALS_DIRECTORY and the
metrics host."""

from __future__ import annotations

import asyncio
import io
import json
import logging
import os
import signal
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest
import structlog

from compd.config.loader import credential_path, load_config
from compd.faces.telemetry import (
    LIBRARY_LOG_FLOOR,
    Metrics,
    clear_secrets,
    configure_logging,
    is_journal_stream,
)
from tests.configs import write_config
from tests.faults.daemon_run import ROOT, RecordingSim
from tests.harness import until_output


@pytest.fixture(autouse=True)
def _reset_logging() -> Iterator[None]:
    yield
    clear_secrets()
    structlog.reset_defaults()
    root = logging.getLogger()
    for handler in [h for h in root.handlers if h.get_name() == "compd"]:
        root.removeHandler(handler)
    root.setLevel(logging.WARNING)
    for name in LIBRARY_LOG_FLOOR:
        logging.getLogger(name).setLevel(logging.NOTSET)


def _journal_env(f: io.TextIOBase) -> dict[str, str]:
    st = os.fstat(f.fileno())
    return {"JOURNAL_STREAM": f"{st.st_dev}:{st.st_ino}"}


def test_journal_stream_lines_carry_the_sd_daemon_priority(
        monkeypatch: pytest.MonkeyPatch) -> None:
    with tempfile.TemporaryFile("w+", encoding="utf-8") as f:
        monkeypatch.setenv("JOURNAL_STREAM", _journal_env(f)["JOURNAL_STREAM"])
        configure_logging(json=True, stream=f)
        log = structlog.get_logger()
        log.info("ready")
        log.warning("cycle_overrun")
        log.error("reload_failed")
        logging.getLogger("asyncua.client").critical("lost")
        f.seek(0)
        lines = f.read().splitlines()
    assert [ln[:3] for ln in lines] == ["<6>", "<4>", "<3>", "<2>"]
    assert lines[1].startswith('<4>{"event": "cycle_overrun"')


def test_no_prefix_when_journal_stream_names_another_file(
        monkeypatch: pytest.MonkeyPatch) -> None:
    with tempfile.TemporaryFile("w+") as ours, tempfile.TemporaryFile("w+") as other:
        assert is_journal_stream(ours, _journal_env(ours))
        assert not is_journal_stream(ours, _journal_env(other))  # stderr redirected
        assert not is_journal_stream(ours, {})
        assert not is_journal_stream(io.StringIO(), _journal_env(ours))
        monkeypatch.setenv("JOURNAL_STREAM", _journal_env(other)["JOURNAL_STREAM"])
        configure_logging(json=True, stream=ours)
        structlog.get_logger().warning("x")
        ours.seek(0)
        assert ours.read().startswith("{")


def test_library_loggers_floor_by_default_and_configurable(tmp_path: Path) -> None:
    buf = io.StringIO()
    configure_logging(json=True, stream=buf)
    logging.getLogger("asyncua.client").info("6 KB of endpoints")
    logging.getLogger("pymodbus.logging").error("frame hex dump")
    assert buf.getvalue() == ""
    cfg = load_config(write_config(tmp_path, base="minimal",
                                   extra='[telemetry]\nlibrary_log_level = "info"\n'))
    assert cfg.raw.telemetry.library_log_level == "info"
    configure_logging(json=True, stream=buf, library_level=cfg.raw.telemetry.library_log_level)
    logging.getLogger("asyncua.client").info("endpoints")
    logging.getLogger("pymodbus.logging").error("frame")
    assert "endpoints" in buf.getvalue() and "frame" in buf.getvalue()
    with pytest.raises(Exception, match="library_log_level"):
        load_config(write_config(tmp_path, base="minimal",
                                 extra='[telemetry]\nlibrary_log_level = "chatty"\n'))


def test_state_directory_from_systemd_unless_the_config_names_one(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    systemd = tmp_path / "var-lib-compd"
    monkeypatch.delenv("STATE_DIRECTORY", raising=False)
    assert load_config(write_config(tmp_path, base="minimal")).state_dir == tmp_path / "state"
    monkeypatch.setenv("STATE_DIRECTORY", f"{systemd}:/var/lib/other")
    cfg = load_config(write_config(tmp_path, base="minimal"))
    assert cfg.state_dir == systemd
    assert cfg.recorder_path == systemd / "samples.sqlite"
    given = load_config(write_config(tmp_path, base="minimal", extra='[state]\ndir = "mine"\n'))
    assert given.state_dir == tmp_path / "mine"  # explicit wins


def test_relative_password_file_from_the_credentials_directory(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """credential_path is what parse_config and read_password both resolve with."""
    creds = tmp_path / "run-credentials"
    creds.mkdir()
    (creds / "controller-password").write_text("from-systemd\n")
    conf = tmp_path / "etc"
    conf.mkdir()
    rel = Path("controller-password")
    monkeypatch.delenv("CREDENTIALS_DIRECTORY", raising=False)
    assert credential_path(rel, conf) == conf / rel
    monkeypatch.setenv("CREDENTIALS_DIRECTORY", str(creds))
    assert credential_path(rel, conf) == creds / rel
    assert credential_path(Path("/etc/x"), conf) == Path("/etc/x")  # absolute: as given
    assert credential_path(Path("other"), conf) == conf / "other"  # not a credential
    assert (credential_path(rel, conf)).read_text().strip() == "from-systemd"


def test_metrics_host_is_configurable(tmp_path: Path) -> None:
    default = load_config(write_config(tmp_path, base="minimal"))
    assert default.raw.telemetry.metrics_host == "127.0.0.1"
    cfg = load_config(write_config(tmp_path, base="minimal", extra='[telemetry]\nmetrics_host'
                                   ' = "::1"\nmetrics_port = 9105\n'))
    assert cfg.raw.telemetry.metrics_host == "::1"
    m = Metrics()
    m.start_http(0, "127.0.0.1")
    try:
        assert m.port
    finally:
        m.stop()


async def test_compd_run_under_journald_prefixes_every_line(
        rec: RecordingSim, tmp_path: Path) -> None:
    """`compd run` with $JOURNAL_STREAM naming its stderr, as systemd starts it."""
    config = write_config(tmp_path, rec.sim.endpoint)
    log = tmp_path / "daemon.log"
    log.touch()
    st = os.stat(log)
    env = {**os.environ, "PYTHONPATH": str(ROOT), "JOURNAL_STREAM": f"{st.st_dev}:{st.st_ino}"}
    env.pop("NOTIFY_SOCKET", None)
    with log.open("ab") as f:
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "compd", "run", str(config),
            stdout=asyncio.subprocess.DEVNULL, stderr=f, env=env, cwd=str(ROOT))
    try:
        await until_output(rec.sim, "heartbeat", lambda v: v >= 3, proc, log)
        proc.send_signal(signal.SIGUSR1)  # a warning line
        beat = (await rec.sim.outputs())["heartbeat"]
        await until_output(rec.sim, "heartbeat", lambda v: v >= beat + 2, proc, log)
        proc.send_signal(signal.SIGTERM)
        assert await asyncio.wait_for(proc.wait(), 20.0) == 0
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
    lines = (await asyncio.to_thread(log.read_text)).splitlines()
    assert lines and all(ln[:1] == "<" and ln[2:4] == ">{" for ln in lines), lines[:3]
    by_event = {json.loads(ln[3:])["event"]: ln[:3] for ln in lines}
    assert by_event["ready"] == "<6>" and by_event["signal_ignored"] == "<4>"
