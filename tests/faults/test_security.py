"""Security of a running daemon (`compd run` subprocesses):

- credentials come from a file or an environment variable: a run against the
  OPC UA sim with Basic256Sha256 SignAndEncrypt and a user name/password
  (from `password_file`) at debug log level; the password appears nowhere in
  its stdout/stderr, the recorder database, the checkpoint or any state file;
  a wrong password (from `password_env`) is refused and not echoed either;
- the start log names the outputs the daemon may write and the config's
  SHA-256; against the Modbus sim, every write request touches only the
  configured output registers;
- a client certificate expiring in 10 days raises `certificate_expiring` at
  start and sets compd_certificate_expiry_timestamp_seconds{role="client"}.

Certificates (a CA, the server, a client valid 10 more days) are made with
`cryptography` at test time, as in tests/drivers/test_opcua_security.py.
"""

from __future__ import annotations

import asyncio
import hashlib
import json
import os
import sys
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest

from drivers.sim.opcua_server import OpcUaSimController, OpcUaSimSecurity
from drivers.sim.ports import free_tcp_port
from models import tomltext
from tests.configs import CONNECT_TIMEOUT_S, write_config
from tests.faults.daemon_run import ROOT, RecordingSim, daemon_env, heartbeat, kill_and_wait
from tests.harness import tail, until
from tests.pki import Pki, server_and_client

from .test_disk_full import _metrics

USER = "operator"
PASSWORD = "K9-unique-Pa55word-7f3e"
WRONG_PASSWORD = "W7-guessed-Pa55word-1c2d"
SERVER_URI = "urn:compd:sim:server"
CLIENT_DAYS = 10.0


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Pki:
    return server_and_client(tmp_path_factory.mktemp("pki"), server_uri=SERVER_URI,
                             client_uri="urn:compd:test:client", client_days=CLIENT_DAYS)


@pytest.fixture
async def opcua_sim(pki: Pki) -> AsyncIterator[OpcUaSimController]:
    sim = OpcUaSimController(security=OpcUaSimSecurity(
        certificate=pki.server_cert, private_key=pki.server_key,
        policies=("Basic256Sha256_SignAndEncrypt",), users={USER: PASSWORD},
        application_uri=SERVER_URI))
    await sim.start()
    await sim.publish({"bearing": 21.0, "ambient": 20.0})
    try:
        yield sim
    finally:
        await sim.stop()


def _opcua_config(sim: OpcUaSimController, pki: Pki, work: Path,
                  credentials: dict[str, str], metrics_port: int) -> Path:
    channels = {name: {"address": sim.channels[name].model_dump(), "unit": "degC",
                       "range": [-20.0, 150.0]} for name in ("bearing", "ambient")}
    outputs = {name: sim.outputs_map[name].model_dump() for name in ("offset", "heartbeat")}
    doc: dict[str, Any] = {
        "machine": {"name": "secure", "period_s": 1.0, "time_scale": 5.0},
        "controller": {"protocol": "opcua", "endpoint": sim.endpoint, "timeout_s": 0.1,
                       # a secured handshake on a loaded machine: late, never lost
                       "connect_timeout_s": CONNECT_TIMEOUT_S,
                       "backoff": {"initial_s": 0.05, "cap_s": 0.2},
                       "security": {"policy": "Basic256Sha256", "mode": "SignAndEncrypt",
                                    "certificate": str(pki.client_cert),
                                    "private_key": str(pki.client_key),
                                    "server_certificate": str(pki.server_cert),
                                    "username": USER, **credentials}},
        "channels": channels,
        "model": {"file": "sp2"},
        "output": {**outputs, "limit_um": 100.0, "slew_um_s": 1.0},
        "state": {"dir": str(work / "state"), "checkpoint_every": 2},
        "recorder": {"commit_every": 2},
        "telemetry": {"log_format": "json", "log_level": "debug",
                      "metrics_port": metrics_port},
    }
    path = work / "compd.toml"
    path.write_text(tomltext.dumps(doc), encoding="utf-8")
    return path


async def _run(config: Path, work: Path, env: dict[str, str]) -> asyncio.subprocess.Process:
    out = (work / "stdout.txt").open("wb")
    err = (work / "stderr.txt").open("wb")
    try:
        return await asyncio.create_subprocess_exec(
            sys.executable, "-m", "compd", "run", str(config), stdin=asyncio.subprocess.DEVNULL,
            stdout=out, stderr=err, env=env, cwd=str(ROOT))
    finally:
        out.close()
        err.close()


def _events(text: str) -> list[dict[str, Any]]:
    out = []
    for line in text.splitlines():
        try:
            ev = json.loads(line)
        except ValueError:
            continue
        if isinstance(ev, dict):
            out.append(ev)
    return out


def _everything_written(work: Path) -> bytes:
    """Every byte the daemon left: stdout, stderr, and all files of its state dir."""
    blobs = [(work / "stdout.txt").read_bytes(), (work / "stderr.txt").read_bytes()]
    blobs += [p.read_bytes() for p in sorted((work / "state").rglob("*")) if p.is_file()]
    return b"\n".join(blobs)


def _assert_no_secret(blob: bytes, secret: str) -> None:
    for form in (secret.encode(), secret.encode("utf-16-le"), secret.encode().hex().encode()):
        assert form not in blob, f"the password leaked as {form!r}"


async def test_password_from_file_never_leaks_and_start_is_audited(
        opcua_sim: OpcUaSimController, pki: Pki, tmp_path: Path) -> None:
    pw_file = tmp_path / "opcua.password"
    pw_file.write_text(PASSWORD + "\n")
    pw_file.chmod(0o600)
    port = free_tcp_port("127.0.0.1")
    config = _opcua_config(opcua_sim, pki, tmp_path, {"password_file": str(pw_file)}, port)
    assert PASSWORD not in config.read_text()
    proc = await _run(config, tmp_path, daemon_env())
    stderr = tmp_path / "stderr.txt"
    try:
        await until(lambda: _heartbeat_at_least(opcua_sim, 3), proc, stderr,
                    "secure daemon cycling", limit_s=60.0)
        metrics = await asyncio.to_thread(_metrics, port)
        proc.terminate()
        assert await asyncio.wait_for(proc.wait(), 120.0) == 0, await asyncio.to_thread(
            tail, stderr)
    finally:
        await kill_and_wait(proc)
    blob = await asyncio.to_thread(_everything_written, tmp_path)
    _assert_no_secret(blob, PASSWORD)
    assert (tmp_path / "state" / "samples.sqlite").exists()
    events = _events(stderr.read_text())
    names = [e.get("event") for e in events]
    # connected at once, or (a slow first secure handshake) on a reconnect
    assert "controller_connected" in names or "controller_reconnected" in names

    # the outputs it may write, with the config's SHA-256, logged at start
    audit = next(e for e in events if e.get("event") == "outputs_configured")
    assert audit["config_sha256"] == hashlib.sha256(config.read_bytes()).hexdigest()
    assert audit["outputs"] == {"offset": opcua_sim.outputs_map["offset"].describe(),
                                "heartbeat": opcua_sim.outputs_map["heartbeat"].describe()}

    # a client certificate that expires in 10 days: a warning and the metric
    expiring = [e for e in events if e.get("event") == "certificate_expiring"]
    assert [e["role"] for e in expiring] == ["client"]
    assert CLIENT_DAYS - 1 < expiring[0]["days_left"] <= CLIENT_DAYS
    assert expiring[0]["level"] == "warning"
    expiry_s = metrics['compd_certificate_expiry_timestamp_seconds{role="client"}']
    days_left = (expiry_s - time.time()) / 86400.0
    assert CLIENT_DAYS - 1 < days_left <= CLIENT_DAYS


async def test_wrong_password_from_env_is_refused_and_not_echoed(
        opcua_sim: OpcUaSimController, pki: Pki, tmp_path: Path) -> None:
    config = _opcua_config(opcua_sim, pki, tmp_path, {"password_env": "COMPD_TEST_OPCUA_PW"},
                           free_tcp_port("127.0.0.1"))
    env = {**daemon_env(), "COMPD_TEST_OPCUA_PW": WRONG_PASSWORD}
    proc = await _run(config, tmp_path, env)
    stderr = tmp_path / "stderr.txt"
    try:
        await until(lambda: "controller_connect_failed" in tail(stderr, 10**7), proc, stderr,
                    "the refusal logged", limit_s=60.0)
        await asyncio.sleep(0.5)  # a few more failed reconnects, logged or not
        proc.terminate()
        await asyncio.wait_for(proc.wait(), 120.0)
    finally:
        await kill_and_wait(proc)
    blob = await asyncio.to_thread(_everything_written, tmp_path)
    _assert_no_secret(blob, WRONG_PASSWORD)
    _assert_no_secret(blob, PASSWORD)
    refusal = next(e for e in _events(stderr.read_text())
                   if e.get("event") == "controller_connect_failed")
    assert USER in refusal["error"]  # it says who was refused, not with what
    assert (await opcua_sim.outputs())["heartbeat"] == 0  # nothing written


async def _heartbeat_at_least(sim: OpcUaSimController, n: float) -> bool:
    return (await sim.outputs())["heartbeat"] >= n


async def test_only_the_configured_outputs_are_written(tmp_path: Path) -> None:
    rec = RecordingSim()
    await rec.start()
    try:
        config = write_config(tmp_path, rec.sim.endpoint)
        # offset only: no heartbeat or status output configured
        text = config.read_text()
        text = "\n".join(line for line in text.splitlines()
                         if not line.startswith(("heartbeat =", "status =")))
        config.write_text(text + "\n")
        proc = await _run(config, tmp_path, daemon_env())
        stderr = tmp_path / "stderr.txt"
        try:
            await rec.sim.publish({"bearing": 23.0})
            await until(lambda: len(rec.writes) >= 10, proc, stderr, "offset writes")
            proc.terminate()
            assert await asyncio.wait_for(proc.wait(), 120.0) == 0
        finally:
            await kill_and_wait(proc)
        writes = [r for r in rec.sim.requests if r.function_code in (5, 6, 15, 16, 22, 23)]
        assert writes
        assert {(r.function_code, r.address, r.count) for r in writes} == {(16, 0, 2)}
        assert await heartbeat(rec.sim) == 0
        audit = next(e for e in _events(stderr.read_text())
                     if e.get("event") == "outputs_configured")
        assert list(audit["outputs"]) == ["offset"]
        assert audit["config_sha256"] == hashlib.sha256(config.read_bytes()).hexdigest()
    finally:
        await rec.stop()


def test_credentials_never_in_the_config(tmp_path: Path) -> None:
    """An inline password is refused without echoing it (and without the run
    reading anything else): the only ways in are a file and an environment
    variable."""
    import subprocess

    config = tmp_path / "compd.toml"
    config.write_text(os.linesep.join([
        "[controller]", 'protocol = "opcua"', 'endpoint = "opc.tcp://127.0.0.1:4840"',
        "[controller.security]", 'policy = "Basic256Sha256"', 'username = "operator"',
        f'password = "{PASSWORD}"', "[channels.bearing]",
        'address = { node = "ns=2;s=Machine.bearing" }', 'unit = "degC"',
        "range = [-20.0, 150.0]", "[model]", 'file = "sp2"', "[output]",
        'offset = { node = "ns=2;s=Machine.offset" }', "limit_um = 100.0",
        "slew_um_s = 1.0"]))
    res = subprocess.run([sys.executable, "-m", "compd", "run", str(config)],
                         capture_output=True, env=daemon_env(), cwd=ROOT, timeout=60,
                         check=False)
    assert res.returncode == 78
    assert b"controller.security" in res.stderr and b"password_file" in res.stderr
    _assert_no_secret(res.stdout + res.stderr, PASSWORD)
