"""Credentials in a URL: refused by the config (check and run, exit 78, the
secret never echoed), and hidden wherever a URL is printed or logged."""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import structlog

from compd.cli import main
from compd.config.urls import redact_urls, url_credentials
from compd.faces.telemetry import configure_logging
from tests.configs import write_config

ROOT = Path(__file__).resolve().parents[3]
SECRET = "s3cr3t-Pa55"


@pytest.mark.parametrize("url", [
    f"opc.tcp://operator:{SECRET}@127.0.0.1:4840",
    f"modbus://admin:{SECRET}@127.0.0.1:502",
    f"s7://x:{SECRET}@127.0.0.1:102",
    "opc.tcp://operator@127.0.0.1:4840",
])
def test_credentials_in_the_endpoint_are_refused_without_echo(
        tmp_path: Path, url: str, capsys: pytest.CaptureFixture[str]) -> None:
    config = write_config(tmp_path, url)
    for argv in (["check", str(config)], ["check", str(config), "--json"],
                 ["run", str(config), "--once"]):
        assert main(argv) == 78
        out = capsys.readouterr()
        assert "controller.endpoint" in out.err and "credentials never go in a URL" in out.err
        assert SECRET not in out.out + out.err


def test_run_as_a_process_never_prints_the_secret(tmp_path: Path) -> None:
    config = write_config(tmp_path, f"modbus://admin:{SECRET}@127.0.0.1:1")
    proc = subprocess.run([sys.executable, "-m", "compd", "run", str(config)],
                          check=False, capture_output=True, text=True, timeout=60, cwd=ROOT,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.returncode == 78
    assert SECRET not in proc.stdout + proc.stderr
    assert "Traceback" not in proc.stderr


def test_plain_endpoints_pass() -> None:
    for url in ("opc.tcp://127.0.0.1:4840/freeopcua/server/", "modbus://127.0.0.1:502",
                "focas://127.0.0.1:8193", "s7://127.0.0.1:102"):
        assert url_credentials(url) is None


def test_redaction_covers_any_url_in_any_log_field() -> None:
    text = f"cannot connect to opc.tcp://operator:{SECRET}@10.0.0.5:4840/x (timeout)"
    assert SECRET not in redact_urls(text)
    assert "opc.tcp://***@10.0.0.5:4840/x" in redact_urls(text)
    assert redact_urls("http://h:1/metrics and s7://u:p@h") == "http://h:1/metrics and s7://***@h"
    buf = io.StringIO()
    configure_logging(json=True, level="info", stream=buf)
    try:
        log = structlog.get_logger("compd")
        log.info("controller_connected", endpoint=f"opc.tcp://u:{SECRET}@h:1")
        log.warning("read_failed", error=ValueError(text), nested={"urls": [text]})
    finally:
        configure_logging(json=True, level="info", stream=io.StringIO())
    lines = [json.loads(ln) for ln in buf.getvalue().splitlines()]
    assert len(lines) == 2
    assert SECRET not in buf.getvalue()
    assert lines[0]["endpoint"] == "opc.tcp://***@h:1"
