"""The OPC UA face's limits ([faces.opcua] max_connections, max_sessions,
handshake_timeout_s; compd.faces.opcua_limits): connections over the cap
evicting silent ones (or closed at once when the others have sessions) and
counted, a connection without a session closed, sessions
over the cap refused, failed logins logged with user and peer (never the
password), the rate-limited log lines, the descriptor budget, and a daemon
under RLIMIT_NOFILE that keeps checkpointing while clients flood its face."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import signal
import sys
from collections.abc import AsyncIterator
from pathlib import Path

import pytest
import structlog
from asyncua.ua.uaerrors import UaStatusCodeError
from prometheus_client import CollectorRegistry

from compd.cli import main
from compd.errors import EX_CONFIG
from compd.faces.opcua_limits import BURST, FD_RESERVE, Guard, Tally, fd_budget
from compd.runtime.daemon import Daemon
from compd.testing import FakeClock
from drivers.sim.modbus_server import ModbusSimController
from drivers.sim.ports import free_tcp_port
from tests.compd.faces.test_opcua_face import OPERATOR, PASSWORD, _client, _face, face_daemon
from tests.configs import write_config
from tests.harness import until
from tests.pki import Pki, server_and_client


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Pki:
    return server_and_client(tmp_path_factory.mktemp("limits-pki"),
                             server_uri="urn:compd:server", client_uri="urn:compd:test:scada")


def _limits(**keys: object) -> str:
    return "".join(f"{k} = {json.dumps(v)}\n" for k, v in keys.items())


def _sample(daemon: Daemon, name: str, **labels: str) -> float:
    value = daemon.metrics.registry.get_sample_value(name, labels)
    return 0.0 if value is None else value


async def _closed_by_server(reader: asyncio.StreamReader) -> bool:
    """True when the server closes the connection (EOF or reset) before 30 s."""
    try:
        return await asyncio.wait_for(reader.read(1), 30.0) == b""
    except (ConnectionResetError, BrokenPipeError):
        return True


@contextlib.asynccontextmanager
async def _sockets(port: int, n: int) -> AsyncIterator[list[tuple[asyncio.StreamReader,
                                                                  asyncio.StreamWriter]]]:
    opened = [await asyncio.open_connection("127.0.0.1", port) for _ in range(n)]
    try:
        yield opened
    finally:
        for _, writer in opened:
            writer.close()
            with contextlib.suppress(OSError):
                await writer.wait_closed()


def _closed(reader: asyncio.StreamReader) -> bool:
    """The server has closed this connection (EOF or reset seen)."""
    return reader.at_eof() or reader.exception() is not None


async def test_connections_beyond_the_cap_evict_silent_ones_and_are_counted(
        sim: ModbusSimController, tmp_path: Path) -> None:
    port = free_tcp_port("127.0.0.1")
    face = _face(port) + _limits(max_connections=4, handshake_timeout_s=300.0)
    with structlog.testing.capture_logs() as logs:
        async with face_daemon(tmp_path, sim, face) as daemon:
            assert _sample(daemon, "compd_opcua_face_connection_limit") == 4
            async with _sockets(port, 4) as first:
                await until(lambda: _sample(daemon, "compd_opcua_face_connections") == 4)
                async with _sockets(port, 12) as more:
                    readers = [r for r, _ in first + more]
                    # each new one takes the place of an older silent one (or, when
                    # all the others were just accepted, is closed itself): 4 stay
                    await until(lambda: sum(_closed(r) for r in readers) == 12)
                    closed = sum(_sample(daemon, "compd_opcua_face_connections_refused_total",
                                         reason=reason) for reason in ("evicted", "limit"))
                    assert closed == 12
                    assert _sample(daemon, "compd_opcua_face_connections_refused_total",
                                   reason="evicted") >= 1
                    assert _sample(daemon, "compd_opcua_face_connections") == 4
            # room again: a client gets its session
            await until(lambda: _sample(daemon, "compd_opcua_face_connections") == 0)
            async with await _client(port) as client:
                assert await client.nodes.server.read_browse_name()
    refused = [e for e in logs if e["event"] == "opcua_connection_refused"]
    assert len(refused) == BURST  # the rest wait for the minute's summary
    assert {e["reason"] for e in refused} <= {"evicted", "limit"}
    assert refused[0]["peer"].startswith("('127.0.0.1'")
    summary = [e for e in logs if e["event"] == "opcua_connection_refused_summary"]
    assert summary and summary[0]["suppressed"] == 12 - BURST  # told at the face's stop


async def test_a_connection_over_the_cap_is_closed_at_once_when_the_others_have_sessions(
        sim: ModbusSimController, tmp_path: Path) -> None:
    port = free_tcp_port("127.0.0.1")
    face = _face(port) + _limits(max_connections=2, handshake_timeout_s=300.0)
    async with face_daemon(tmp_path, sim, face) as daemon, \
            await _client(port) as one, await _client(port) as two:
        async with _sockets(port, 3) as over:
            for reader, _ in over:
                assert await _closed_by_server(reader)
        assert _sample(daemon, "compd_opcua_face_connections_refused_total",
                       reason="limit") == 3
        assert _sample(daemon, "compd_opcua_face_connections_refused_total",
                       reason="evicted") == 0
        for client in (one, two):  # never evicted: they have sessions
            assert await client.nodes.server.read_browse_name()


async def test_a_connection_without_a_session_is_closed_after_the_handshake_timeout(
        sim: ModbusSimController, tmp_path: Path) -> None:
    port = free_tcp_port("127.0.0.1")
    # long enough for the client's own login under load; the raw socket waits it out
    face = _face(port) + _limits(handshake_timeout_s=2.0)
    async with face_daemon(tmp_path, sim, face) as daemon, await _client(port) as client:
        async with _sockets(port, 1) as [(reader, _)]:  # connects, says nothing
            assert await _closed_by_server(reader)
        assert _sample(daemon, "compd_opcua_face_connections_refused_total",
                       reason="handshake_timeout") == 1
        # a client with a session (connected first, so its timer is long past) stays
        assert await client.nodes.server.read_browse_name()


async def test_sessions_beyond_the_cap_are_refused(
        sim: ModbusSimController, tmp_path: Path) -> None:
    port = free_tcp_port("127.0.0.1")
    face = _face(port) + _limits(max_sessions=1)
    async with face_daemon(tmp_path, sim, face) as daemon:
        async with await _client(port) as first:
            with pytest.raises(UaStatusCodeError, match="TooManySessions"):
                async with await _client(port):
                    pass
            assert await first.nodes.server.read_browse_name()
        assert _sample(daemon, "compd_opcua_face_sessions_refused_total",
                       reason="max_sessions") == 1
        await until(lambda: _sample(daemon, "compd_opcua_face_connections") == 0)
        async with await _client(port) as second:  # the first one's session is gone
            assert await second.nodes.server.read_browse_name()


async def test_a_failed_login_is_logged_with_user_and_peer_never_the_password(
        sim: ModbusSimController, tmp_path: Path, pki: Pki,
        caplog: pytest.LogCaptureFixture) -> None:
    port = free_tcp_port("127.0.0.1")
    async with face_daemon(tmp_path, sim, _face(port, secure=pki)) as daemon:
        with structlog.testing.capture_logs() as logs:
            for user, password in ((OPERATOR, "guess-1"), ("mallory", PASSWORD)):
                with pytest.raises(UaStatusCodeError):
                    async with await _client(port, pki, user, password):
                        pass
            async with await _client(port, pki, OPERATOR, PASSWORD):
                pass  # the right one is no failure
        failed = [e for e in logs if e["event"] == "opcua_login_failed"]
        assert [e["user"] for e in failed] == [OPERATOR, "mallory"]
        assert all(e["peer"].startswith("('127.0.0.1'") for e in failed)
        assert _sample(daemon, "compd_opcua_face_logins_failed_total") == 2
    text = repr(logs) + caplog.text
    assert "guess-1" not in text and PASSWORD not in text
    # the server's own anonymous "sending service fault response" line is not repeated
    assert "sending service fault" not in caplog.text


def test_the_summary_counts_what_the_first_lines_did_not_say() -> None:
    clock = FakeClock(period_s=1.0)
    log = structlog.get_logger("test")
    tally = Tally("opcua_login_failed", log, clock)
    with structlog.testing.capture_logs() as logs:
        for i in range(20):
            tally.note(user="root" if i % 2 else "admin", peer=f"('10.0.0.{i % 3}', {4000 + i})")
            clock.advance(1.0)
        tally.flush()  # 20 s: the minute is not over
        assert [e["event"] for e in logs] == ["opcua_login_failed"] * BURST
        clock.advance(60.0)
        tally.flush()
    summary = logs[-1]
    assert summary["event"] == "opcua_login_failed_summary"
    assert summary["suppressed"] == 20 - BURST and summary["total"] == 20
    assert sum(summary["users"].values()) == 20 - BURST
    assert set(summary["peers"]) == {"10.0.0.0", "10.0.0.1", "10.0.0.2"}
    with structlog.testing.capture_logs() as later:
        tally.note(user="admin", peer="('10.0.0.9', 1)")  # a new minute: told at once
    assert [e["event"] for e in later] == ["opcua_login_failed"]


def test_the_connection_limit_leaves_descriptors_for_the_cycle() -> None:
    assert fd_budget(1024, 40) == 1024 - 40 - FD_RESERVE - 16
    assert fd_budget(-1, 40) > 10_000  # unlimited
    guard = Guard(max_connections=32, max_sessions=16, handshake_timeout_s=10.0)
    assert guard.fit_to_descriptors(1024, 40) == 32
    with structlog.testing.capture_logs() as logs:
        assert guard.fit_to_descriptors(FD_RESERVE + 16 + 40 + 10, 40) == 10
    assert logs[0]["event"] == "opcua_face_connections_capped"
    with pytest.raises(ValueError, match="RLIMIT_NOFILE"):
        guard.fit_to_descriptors(FD_RESERVE + 16 + 40, 40)


@pytest.mark.parametrize(("keys", "word"), [
    ("max_connections = 0\n", "max_connections"),
    ("max_sessions = 0\n", "max_sessions"),
    ("handshake_timeout_s = 0\n", "handshake_timeout_s"),
    ("max_conections = 8\n", "max_connections"),  # did you mean
])
def test_the_config_refuses_a_bad_limit_by_name(
        tmp_path: Path, keys: str, word: str, capsys: pytest.CaptureFixture[str]) -> None:
    path = write_config(tmp_path, "modbus://127.0.0.1:5020")
    path.write_text(path.read_text(encoding="utf-8") + _face(5999) + keys, encoding="utf-8")
    assert main(["check", str(path)]) == EX_CONFIG
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "faces.opcua" in err[0] and word in err[0], err


def _registry_has_no_face(registry: CollectorRegistry) -> bool:
    return registry.get_sample_value("compd_opcua_face_connections") is None


async def test_the_face_counts_leave_the_registry_with_the_face(
        sim: ModbusSimController, tmp_path: Path) -> None:
    port = free_tcp_port("127.0.0.1")
    async with face_daemon(tmp_path, sim, _face(port)) as daemon:
        assert not _registry_has_no_face(daemon.metrics.registry)
    assert _registry_has_no_face(daemon.metrics.registry)


NOFILE = 360  # the child's limit: the face's budget is ~50 with ~40 open


async def test_a_flood_of_idle_connections_leaves_the_cycle_its_descriptors(
        sim: ModbusSimController, tmp_path: Path) -> None:
    """`compd run` under RLIMIT_NOFILE=360 (a subprocess), 500 idle TCP
    connections to its face: no EMFILE anywhere, no accept() traceback, and a
    checkpoint written while the face is full."""
    port = free_tcp_port("127.0.0.1")
    path = write_config(tmp_path, sim.endpoint, time_scale=20.0, checkpoint_every=5)
    path.write_text(path.read_text(encoding="utf-8") + _face(port)
                    + _limits(max_connections=1000, handshake_timeout_s=300.0),
                    encoding="utf-8")

    # the child lowers its own limit (as systemd's LimitNOFILE= would) and runs `compd run`
    child = ("import resource, sys; resource.setrlimit(resource.RLIMIT_NOFILE, "
             f"({NOFILE}, {NOFILE})); from compd.cli import main; sys.exit(main(sys.argv[1:]))")
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-c", child, "run", str(path), stdout=asyncio.subprocess.DEVNULL,
        stderr=asyncio.subprocess.PIPE, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    lines: list[str] = []

    async def collect() -> None:
        assert proc.stderr is not None
        async for raw in proc.stderr:
            lines.append(raw.decode(errors="replace"))

    reader = asyncio.get_running_loop().create_task(collect())
    checkpoint = tmp_path / "state" / "checkpoint.json"
    held: list[asyncio.StreamWriter] = []
    try:
        await until(lambda: any("opcua_face_started" in ln for ln in lines)
                    or proc.returncode is not None, limit_s=60.0)
        assert proc.returncode is None, "".join(lines)[-3000:]
        started = json.loads(next(ln for ln in lines if "opcua_face_started" in ln))
        cap = started["max_connections"]
        assert 0 < cap < NOFILE - FD_RESERVE  # lowered to the descriptors there are
        async def connect() -> None:
            with contextlib.suppress(OSError, TimeoutError):
                _, writer = await asyncio.wait_for(
                    asyncio.open_connection("127.0.0.1", port), 10.0)
                held.append(writer)

        # all at once, as a flood comes: one after the other, each connect beyond the
        # face's accept backlog waited out a SYN retransmit (1 s) on its own
        await asyncio.gather(*(connect() for _ in range(500)))
        await until(lambda: sum('"opcua_connection_refused' in ln for ln in lines) >= BURST,
                    limit_s=60.0)
        assert checkpoint.exists()
        before = checkpoint.stat().st_mtime_ns
        # the face is full (its cap held, the rest refused): the cycle checkpoints on
        await until(lambda: checkpoint.stat().st_mtime_ns != before, limit_s=60.0)
    finally:
        for writer in held:
            writer.close()
        if proc.returncode is None:
            proc.send_signal(signal.SIGTERM)
        rc = await asyncio.wait_for(proc.wait(), 60.0)
        await reader
    text = "".join(lines)
    assert rc == 0, text[-3000:]
    assert "Too many open files" not in text and "out of system resource" not in text
    assert "checkpoint_failed" not in text and "Traceback" not in text
