"""The operator always reaches SetHold on the OPC UA face: a new connection at
the limit evicts the one that has waited longest for its handshake (silent
ones first, never one with a session, never one the loop has not yet read),
and anonymous readers leave ``reserved_sessions`` to the operator
(compd.faces.opcua_limits). Against the real asyncua server of a running
daemon on 127.0.0.1, with sockets that say nothing reopened as soon as the face
closes them, and with anonymous sessions holding their whole share."""

from __future__ import annotations

import asyncio
import contextlib
import json
import socket
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest
from asyncua.ua.uaerrors import UaStatusCodeError

from compd.cli import main
from compd.errors import EX_CONFIG
from compd.faces.opcua_limits import (
    ACCEPT_BURST,
    FD_RESERVE,
    Connection,
    Guard,
    _Refused,
    _Tracked,
    pending_bytes,
)
from compd.runtime.daemon import Daemon
from compd.testing import FakeClock
from drivers.sim.modbus_server import ModbusSimController
from drivers.sim.ports import free_tcp_port
from tests.compd.faces.test_opcua_face import (
    OPERATOR,
    PASSWORD,
    _client,
    _face,
    _machine,
    face_daemon,
)
from tests.configs import write_config
from tests.harness import until
from tests.pki import Pki, server_and_client


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Pki:
    return server_and_client(tmp_path_factory.mktemp("lockout-pki"),
                             server_uri="urn:compd:server", client_uri="urn:compd:test:scada")


def _limits(**keys: object) -> str:
    return "".join(f"{k} = {json.dumps(v)}\n" for k, v in keys.items())


def _sample(daemon: Daemon, name: str, **labels: str) -> float:
    value = daemon.metrics.registry.get_sample_value(name, labels)
    return 0.0 if value is None else value


@contextlib.asynccontextmanager
async def _silent_flood(port: int, n: int) -> AsyncIterator[list[int]]:
    """`n` TCP connections that never send a byte, each reopened as soon as the
    server closes it; yields [connections opened so far]."""
    opened = [0]

    async def one() -> None:
        while True:
            try:
                reader, writer = await asyncio.open_connection("127.0.0.1", port)
            except OSError:
                await asyncio.sleep(0.01)
                continue
            opened[0] += 1
            try:
                await reader.read(1)  # b"" (or a reset) once the face closes it
            except OSError:
                pass
            finally:
                writer.close()
            await asyncio.sleep(0.005)  # reopened at once, without starving the test's loop

    tasks = [asyncio.create_task(one()) for _ in range(n)]
    try:
        yield opened
    finally:
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)


async def _operator_holds(port: int, pki: Pki) -> None:
    """The operator logs in and SetHold(true) is applied."""
    async with await _client(port, pki, OPERATOR, PASSWORD) as op:
        idx, machine = await _machine(op)
        assert await machine.call_method(f"{idx}:SetHold", True) is True


async def test_silent_sockets_at_the_cap_are_evicted_for_the_operator(
        sim: ModbusSimController, tmp_path: Path, pki: Pki) -> None:
    port = free_tcp_port("127.0.0.1")
    # the handshake timeout never plays here: only eviction makes room
    face = _face(port, secure=pki) + _limits(max_connections=8, handshake_timeout_s=300.0)
    async with face_daemon(tmp_path, sim, face) as daemon, _silent_flood(port, 8) as opened:
        await until(lambda: _sample(daemon, "compd_opcua_face_connections") == 8)
        await until(lambda: opened[0] >= 8)
        for _ in range(3):  # the flood reopens all the while: each connect gets in
            evicted = _sample(daemon, "compd_opcua_face_connections_refused_total",
                              reason="evicted")
            await _operator_holds(port, pki)
            assert _sample(daemon, "compd_opcua_face_connections_refused_total",
                           reason="evicted") > evicted
        assert daemon.running.cycle is not None and daemon.running.cycle.health.operator_hold
        # the evicted sockets came back: the cap was full while the operator got in
        await until(lambda: opened[0] > 8 + 3)
        await until(lambda: _sample(daemon, "compd_opcua_face_connections") == 8)
        assert _sample(daemon, "compd_opcua_face_connections_refused_total",
                       reason="handshake_timeout") == 0


async def test_anonymous_sessions_leave_the_operator_a_session(
        sim: ModbusSimController, tmp_path: Path, pki: Pki) -> None:
    port = free_tcp_port("127.0.0.1")
    face = _face(port, secure=pki, anonymous=True) + _limits(max_sessions=4)
    async with face_daemon(tmp_path, sim, face) as daemon, contextlib.AsyncExitStack() as stack:
        # anonymous readers get max_sessions - reserved_sessions (default 1) = 3
        for _ in range(3):
            anon = await stack.enter_async_context(await _client(port, pki))
            assert await anon.nodes.server.read_browse_name()
        with pytest.raises(UaStatusCodeError, match="TooManySessions"):
            async with await _client(port, pki):
                pass
        assert _sample(daemon, "compd_opcua_face_sessions_refused_total",
                       reason="anonymous_share") == 1
        await _operator_holds(port, pki)
        assert daemon.running.cycle is not None and daemon.running.cycle.health.operator_hold
        assert _sample(daemon, "compd_opcua_face_sessions_refused_total",
                       reason="max_sessions") == 0


async def test_both_floods_at_once_still_leave_the_operator_sethold(
        sim: ModbusSimController, tmp_path: Path, pki: Pki) -> None:
    """Anonymous sessions hold their share, half the connections, and silent
    sockets the rest: the operator's connect evicts a silent one."""
    port = free_tcp_port("127.0.0.1")
    face = _face(port, secure=pki, anonymous=True) + _limits(
        max_connections=8, max_sessions=16, handshake_timeout_s=300.0)
    async with face_daemon(tmp_path, sim, face) as daemon, contextlib.AsyncExitStack() as stack:
        # the anonymous share is bounded by the connections: 8 // 2 = 4
        for _ in range(4):
            await stack.enter_async_context(await _client(port, pki))
        with pytest.raises(UaStatusCodeError, match="TooManySessions"):
            async with await _client(port, pki):
                pass
        async with _silent_flood(port, 4):
            await until(lambda: _sample(daemon, "compd_opcua_face_connections") == 8)
            await _operator_holds(port, pki)
        assert daemon.running.cycle is not None and daemon.running.cycle.health.operator_hold


class _FakeTransport:
    """Enough of an asyncio transport for `Guard.victim` and `Guard.evict`."""

    def __init__(self, sock: socket.socket | None = None) -> None:
        self.sock, self.aborted = sock, False

    def is_closing(self) -> bool:
        return self.aborted

    def abort(self) -> None:
        self.aborted = True

    close = abort

    def get_extra_info(self, name: str) -> Any:
        return self.sock if name == "socket" else ("127.0.0.1", 40000)


def _connect(guard: Guard) -> asyncio.Protocol:
    """A connection accepted (its transport is made later, as asyncio does);
    one refused is closed at once, as it is on connection_made."""
    protocol = guard.factory(asyncio.Protocol)()
    if isinstance(protocol, _Refused):
        refused = _FakeTransport()
        protocol.connection_made(refused)  # type: ignore[arg-type]
        assert refused.aborted
    return protocol


def _held(guard: Guard) -> list[Connection]:
    return list(guard.connections)


def test_the_victim_is_the_oldest_silent_connection_then_a_stalled_handshake() -> None:
    clock = FakeClock()
    guard = Guard(max_connections=3, max_sessions=3, handshake_timeout_s=10.0, clock=clock)
    a, b, c = (_connect(guard) for _ in range(3))
    assert all(isinstance(p, _Tracked) for p in (a, b, c))
    # accepted in one burst: not one of them has been read yet, so none is evicted
    assert isinstance(_connect(guard), _Refused) and guard.refused["limit"] == 1
    first, second, third = _held(guard)
    fakes = [_FakeTransport() for _ in range(3)]
    for conn, fake in zip((first, second, third), fakes, strict=True):
        conn.transport = fake  # type: ignore[assignment]
    first.spoke = True  # its Hello came: logging in
    third.activated = True  # a session: never evicted
    assert guard.victim() is second
    assert isinstance(_connect(guard), _Tracked)
    assert second not in guard.connections and guard.refused["evicted"] == 1
    assert fakes[1].aborted and not fakes[0].aborted
    # one logging in, one with a session, one not read yet: the newcomer is refused
    assert guard.victim() is None
    assert isinstance(_connect(guard), _Refused) and guard.refused["limit"] == 2
    clock.advance(4.9)
    assert guard.victim() is None
    clock.advance(0.1)  # half the handshake timeout: a login stalled on purpose
    assert guard.victim() is first
    newest = _held(guard)[-1]
    newest.transport = _FakeTransport()  # type: ignore[assignment]
    assert guard.victim() is newest  # silent now, and silent goes first, however young
    newest.activated = first.activated = True
    assert guard.victim() is None  # sessions only: the next one is refused
    assert isinstance(_connect(guard), _Refused) and guard.refused["limit"] == 3


def test_a_hello_waiting_in_the_kernel_counts_as_spoken() -> None:
    guard = Guard(max_connections=2, max_sessions=2, handshake_timeout_s=10.0)
    _connect(guard)
    _connect(guard)
    older, newer = _held(guard)
    server_a, client_a = socket.socketpair()
    server_b, client_b = socket.socketpair()
    with server_a, client_a, server_b, client_b:
        client_a.sendall(b"HELF")  # the loop has not read it yet
        assert pending_bytes(_FakeTransport(server_a)) == 4  # type: ignore[arg-type]
        assert pending_bytes(_FakeTransport(server_b)) == 0  # type: ignore[arg-type]
        older.transport = _FakeTransport(server_a)  # type: ignore[assignment]
        newer.transport = _FakeTransport(server_b)  # type: ignore[assignment]
        assert guard.victim() is newer and older.spoke


def test_anonymous_sessions_stop_short_of_the_reserve() -> None:
    guard = Guard(max_connections=8, max_sessions=4, reserved_sessions=1,
                  handshake_timeout_s=10.0)
    assert guard.anonymous_limit == 3
    # the descriptors leave 4 connections: anonymous sessions take half of them
    assert guard.fit_to_descriptors(FD_RESERVE + ACCEPT_BURST + 4, 0) == 4
    assert guard.anonymous_limit == 2
    assert guard.fit_to_descriptors(FD_RESERVE + ACCEPT_BURST + 1, 0) == 1
    assert guard.anonymous_limit == 0
    assert Guard(max_connections=8, max_sessions=4, handshake_timeout_s=10.0) \
        .anonymous_limit == 4  # no operator, nothing kept back


@pytest.mark.parametrize(("keys", "word"), [
    ("anonymous_read = true\nreserved_sessions = 4\nmax_sessions = 4\n", "reserved_sessions"),
    ("anonymous_read = true\nmax_connections = 1\n", "max_connections"),
    ("reserved_sessions = 0\n", "reserved_sessions"),
])
def test_the_config_refuses_a_reserve_that_leaves_no_room_by_name(
        tmp_path: Path, pki: Pki, keys: str, word: str,
        capsys: pytest.CaptureFixture[str]) -> None:
    path = write_config(tmp_path, "modbus://127.0.0.1:5020")
    (tmp_path / "operator.pw").write_text(PASSWORD + "\n", encoding="utf-8")
    face = _face(5999, secure=pki).replace("anonymous_read = false\n", "")
    path.write_text(path.read_text(encoding="utf-8") + face + keys, encoding="utf-8")
    assert main(["check", str(path)]) == EX_CONFIG
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "faces.opcua" in err[0] and word in err[0], err
