"""compd's OPC UA server face ([faces.opcua]) against a running daemon on the
simulated Modbus controller, read with asyncua's client: the namespace, values
per cycle, the fault state by name, writes refused, SetHold for the operator
only (the offset holds, then slews back), a secure endpoint with a certificate
and a user, the config's refusals, and a face that cannot start."""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import itertools
import math
import socket
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest
import structlog
from asyncua import ua
from asyncua.client.client import Client
from asyncua.common.node import Node
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256
from asyncua.ua.uaerrors import BadUserAccessDenied, UaStatusCodeError

from compd.cli import main
from compd.config.loader import load_config
from compd.core.faults import FaultState
from compd.errors import EX_CONFIG, ConfigError
from compd.faces import opcua_shared
from compd.faces.opcua_face import NAMESPACE, release_all
from compd.runtime.daemon import Daemon
from compd.runtime.sdnotify import Notifier
from drivers.sim.modbus_server import ModbusSimController
from drivers.sim.ports import free_tcp_port
from tests.configs import write_config
from tests.drivers.test_opcua_space import count_builds
from tests.harness import until
from tests.pki import Pki, server_and_client

#: generous: a request that outlasts it makes asyncua drop the session ("client is
#: disconnected"), and a loaded PC makes a request slower, never a test red; also the
#: period of asyncua's own liveness probe, which waits at most that period for the
#: server's answer (1 s by default: a busy loop's late answer dropped the session)
REQUEST_TIMEOUT_S = 60.0

OPERATOR, PASSWORD = "setter", "h0ld-Pa55word"


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Pki:
    return server_and_client(tmp_path_factory.mktemp("face-pki"),
                             server_uri="urn:compd:server", client_uri="urn:compd:test:scada")


def _face(port: int, *, secure: Pki | None = None, anonymous: bool = False) -> str:
    if secure is None:
        return (f'\n[faces.opcua]\nenabled = true\nport = {port}\npolicy = "None"\n'
                "insecure = true\n")
    return (f'\n[faces.opcua]\nenabled = true\nport = {port}\n'
            f'certificate = "{secure.server_cert}"\nprivate_key = "{secure.server_key}"\n'
            f'operator = "{OPERATOR}"\noperator_password_file = "operator.pw"\n'
            f"anonymous_read = {'true' if anonymous else 'false'}\n")


@contextlib.asynccontextmanager
async def face_daemon(tmp_path: Path, sim: ModbusSimController, face: str,
                      slew_um_s: float = 1.0) -> AsyncIterator[Daemon]:
    path = write_config(tmp_path, sim.endpoint, time_scale=20.0, slew_um_s=slew_um_s)
    (tmp_path / "operator.pw").write_text(PASSWORD + "\n", encoding="utf-8")
    path.write_text(path.read_text(encoding="utf-8") + face, encoding="utf-8")
    async with running_daemon(path) as daemon:
        yield daemon


@contextlib.asynccontextmanager
async def running_daemon(path: Path) -> AsyncIterator[Daemon]:
    """The daemon of the config at `path`, once it completed 3 cycles and its OPC UA
    face has started; stopped (exit 0) and the face's servers released after."""
    daemon = Daemon(load_config(path), notifier=Notifier(None))
    task = asyncio.create_task(daemon.run())
    try:
        await until(lambda: daemon.telemetry.complete_cycles >= 3 or task.done())
        assert not task.done(), "the daemon ended early"
        # the face starts beside the loop (seconds): compensation did not wait for it
        await until(lambda: daemon.opcua.starting is None or daemon.opcua.starting.done())
        yield daemon
    finally:
        daemon.request_stop()
        assert await asyncio.wait_for(task, 120.0) == 0
        await release_all()


async def _client(port: int, pki: Pki | None = None, user: str | None = None,
                  password: str | None = None) -> Client:
    client = Client(f"opc.tcp://127.0.0.1:{port}", timeout=REQUEST_TIMEOUT_S,
                    watchdog_intervall=REQUEST_TIMEOUT_S)
    if pki is not None:
        await client.set_security(SecurityPolicyBasic256Sha256, str(pki.client_cert),
                                  str(pki.client_key), server_certificate=str(pki.server_cert),
                                  mode=ua.MessageSecurityMode.SignAndEncrypt)
        client.application_uri = "urn:compd:test:scada"
    if user is not None:
        client.set_user(user)
        client.set_password(password or "")
    return client


async def _machine(client: Client) -> tuple[int, Node]:
    idx = await client.get_namespace_index(NAMESPACE)
    machine = await client.nodes.objects.get_child(f"{idx}:test")
    return idx, machine


async def _value(machine: Node, idx: int, *path: str) -> object:
    node = await machine.get_child([f"{idx}:{p}" for p in path])
    return await node.read_value()


async def _becomes(machine: Node, idx: int, path: tuple[str, ...], expected: object,
                   tries: int = 12_000) -> None:
    """The face writes between cycles on its own thread: poll until it shows
    `expected` (at most 2 min: a loaded machine is slower, never red)."""
    for _ in range(tries):
        if await _value(machine, idx, *path) == expected:
            return
        await asyncio.sleep(0.01)
    assert await _value(machine, idx, *path) == expected


async def test_the_namespace_follows_the_cycle_and_is_read_only(
        sim: ModbusSimController, tmp_path: Path) -> None:
    port = free_tcp_port("127.0.0.1")
    async with face_daemon(tmp_path, sim, _face(port)) as daemon:
        client = await _client(port)
        async with client:
            idx, machine = await _machine(client)
            await _becomes(machine, idx, ("FaultStateName",), "ok")
            await _becomes(machine, idx, ("Channels", "bearing", "Value"), 20.0)
            await _becomes(machine, idx, ("Channels", "bearing", "Valid"), True)
            beat = await _value(machine, idx, "Heartbeat")
            for _ in range(12_000):  # updated per cycle
                if await _value(machine, idx, "Heartbeat") != beat:
                    break
                await asyncio.sleep(0.01)
            assert await _value(machine, idx, "Heartbeat") != beat
            assert await _value(machine, idx, "Model", "Sha256") == daemon.running.cfg.model_sha256
            terms = await (await machine.get_child(f"{idx}:Terms")).get_children()
            assert len(terms) == len(daemon.running.cfg.model.terms)
            # the FaultState variable's data type is an enumeration with names
            state = await machine.get_child(f"{idx}:FaultState")
            dtype = await state.read_data_type()
            definition = await client.get_node(dtype).read_data_type_definition()
            assert isinstance(definition, ua.EnumDefinition)
            assert [f.Name for f in definition.Fields][:2] == ["init", "ok"]
            assert "write_fault" in [f.Name for f in definition.Fields]
            # everyone reads; nobody writes
            with pytest.raises(BadUserAccessDenied):
                await state.write_value(ua.Variant(0, ua.VariantType.Int32))
            # and a method call without the operator is refused
            with pytest.raises(UaStatusCodeError):
                await machine.call_method(f"{idx}:SetHold", True)
            # a fault shows by name
            await sim.publish({"bearing": 500.0, "ambient": 20.0})
            await until(lambda: daemon.loop.last_result is not None
                        and daemon.loop.last_result.state.value == "hold")
            await _becomes(machine, idx, ("FaultStateName",), "hold")
            await _becomes(machine, idx, ("Channels", "bearing", "Valid"), False)
        assert daemon.running.cycle is not None
        assert daemon.running.cycle.health.operator_hold is False


async def test_each_face_has_a_copy_of_the_standard_space_built_once(
        sim: ModbusSimController, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The face's server takes the standard address space from the process's
    template (`drivers.opcua_space`): built by the first face, copied for the
    next; each has its own namespace array."""
    builds = count_builds(monkeypatch)
    for run in ("one", "two"):
        port = free_tcp_port("127.0.0.1")
        (tmp_path / run).mkdir()
        async with face_daemon(tmp_path / run, sim, _face(port)):
            client = await _client(port)
            async with client:
                assert await client.get_namespace_array() == [
                    "http://opcfoundation.org/UA/", "urn:compd:server", NAMESPACE]
                _, machine = await _machine(client)
                assert (await machine.read_browse_name()).Name == "test"
        assert len(builds) == 1, run


async def test_a_server_that_starts_before_its_constructor_returns_keeps_its_namespace(
        sim: ModbusSimController, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The face's server starts on its own thread while the daemon's thread is
    still in `SharedServer.__init__`; with the standard space already built the
    start can finish first, and it must keep the namespace index and fault type
    it set (the machine's object is in the face's namespace, not in OPC UA's 0).
    Here the submit of the start waits for it: the start always wins that race."""
    submit = opcua_shared.SharedServer.submit

    def start_first(self: opcua_shared.SharedServer,
                    coro: Any) -> concurrent.futures.Future[Any]:
        name = coro.__qualname__
        future = submit(self, coro)
        if name == "SharedServer.start":
            with contextlib.suppress(Exception):
                future.result(timeout=120.0)
        return future

    monkeypatch.setattr(opcua_shared.SharedServer, "submit", start_first)
    port = free_tcp_port("127.0.0.1")
    async with face_daemon(tmp_path, sim, _face(port)):
        client = await _client(port)
        async with client:
            idx, machine = await _machine(client)
            assert idx == 2 and machine.nodeid.NamespaceIndex == idx
            state = await machine.get_child(f"{idx}:FaultState")
            assert (await state.read_data_type()).NamespaceIndex == idx


async def test_sethold_is_the_operators_and_holds_then_slews_back(
        sim: ModbusSimController, tmp_path: Path, pki: Pki,
        caplog: pytest.LogCaptureFixture) -> None:
    port = free_tcp_port("127.0.0.1")
    async with face_daemon(tmp_path, sim, _face(port, secure=pki, anonymous=True),
                           slew_um_s=2.0) as daemon:
        # anonymous reads, but may not hold
        async with await _client(port, pki) as anon:
            idx, machine = await _machine(anon)
            await _becomes(machine, idx, ("FaultStateName",), "ok")
            with pytest.raises(UaStatusCodeError):
                await machine.call_method(f"{idx}:SetHold", True)
        # a wrong password is no session at all
        with pytest.raises(UaStatusCodeError):
            async with await _client(port, pki, OPERATOR, "guess"):
                pass
        async with await _client(port, pki, OPERATOR, PASSWORD) as op:
            idx, machine = await _machine(op)
            with structlog.testing.capture_logs() as logs:
                assert await machine.call_method(f"{idx}:SetHold", True) is True
            audit = [e for e in logs if e["event"] == "opcua_set_hold"]
            assert audit and audit[0]["user"] == OPERATOR and audit[0]["hold"] is True
            assert audit[0]["peer"].startswith("('127.0.0.1'")  # who, from where, what
            assert daemon.running.cycle is not None and daemon.running.cycle.health.operator_hold
            held = daemon.running.cycle.output.current_um
            await sim.publish({"bearing": 30.0, "ambient": 20.0})  # the model moves away
            await until(lambda: daemon.loop.last_result is not None
                        and daemon.loop.last_result.model_um is not None
                        and daemon.loop.last_result.model_um > held + 5.0)
            assert daemon.running.cycle.output.current_um == held  # held where it was
            assert daemon.loop.last_result is not None
            assert daemon.loop.last_result.status & (1 << 12)
            await _becomes(machine, idx, ("OperatorHold",), True)
            assert await machine.call_method(f"{idx}:SetHold", False) is True
            await until(lambda: daemon.running.cycle is not None
                        and daemon.running.cycle.output.current_um > held + 1.0)
            # released: back to the model at the slew limit (2 µm/s, 1 s machine period)
            seen: list[tuple[int, float]] = []  # (cycle, offset) as the test sees them
            for _ in range(5):
                await until(lambda: daemon.loop.last_result is not None
                            and daemon.loop.last_result.sequence not in [q for q, _ in seen[-1:]])
                assert daemon.loop.last_result is not None
                seen.append((daemon.loop.last_result.sequence, daemon.loop.last_result.stage_um))
            for (qa, a), (qb, b) in itertools.pairwise(seen):
                # 2 µm/s over a cycle's machine time: at most 2 periods (the output
                # stage's bound on a late cycle's dt), so 4 µm a cycle; a jump is ~10
                # (1e-6: each step starts from the float32 the controller holds)
                assert 0.0 <= b - a <= 4.0 * (qb - qa) + 1e-6


async def test_rezero_is_the_operators_audited_and_ramps_without_a_step(
        sim: ModbusSimController, tmp_path: Path, pki: Pki) -> None:
    port = free_tcp_port("127.0.0.1")
    async with face_daemon(tmp_path, sim, _face(port, secure=pki, anonymous=True),
                           slew_um_s=2.0) as daemon:
        await sim.publish({"bearing": 22.0, "ambient": 20.0})  # warm: a prediction
        await until(lambda: daemon.loop.last_result is not None
                    and daemon.loop.last_result.model_um is not None
                    and daemon.loop.last_result.model_um > 5.0)
        # anonymous reads, but may not re-zero: refused, audited nowhere, nothing changed
        async with await _client(port, pki) as anon:
            idx, machine = await _machine(anon)
            with structlog.testing.capture_logs() as logs, \
                    pytest.raises(UaStatusCodeError):
                await machine.call_method(f"{idx}:Rezero")
            assert not [e for e in logs if e["event"] == "opcua_rezero"]
        assert daemon.running.cycle is not None and daemon.running.cycle.models.zero_by is None
        async with await _client(port, pki, OPERATOR, PASSWORD) as op:
            idx, machine = await _machine(op)
            before = daemon.running.cycle.output.current_um
            with structlog.testing.capture_logs() as logs:
                assert await machine.call_method(f"{idx}:Rezero") is True
            audit = [e for e in logs if e["event"] == "opcua_rezero"]
            assert audit and audit[0]["user"] == OPERATOR and audit[0]["applied"] is True
            assert audit[0]["peer"].startswith("('127.0.0.1'")  # who, from where, what
            await until(lambda: daemon.running.cycle is not None
                        and daemon.running.cycle.models.zero_by is not None)
            by = daemon.running.cycle.models.zero_by
            assert by is not None and by.startswith(f"opcua: {OPERATOR} from ")
            assert daemon.running.cycle.models.zero_um > 5.0  # the prediction taken as zero
            # the target is now ~0: the offset ramps down at the slew limit, never a step
            await until(lambda: daemon.running.cycle is not None
                        and daemon.running.cycle.output.current_um < before - 3.0)
            seen: list[tuple[int, float]] = []
            for _ in range(4):
                await until(lambda: daemon.loop.last_result is not None
                            and daemon.loop.last_result.sequence not in [q for q, _ in seen[-1:]])
                assert daemon.loop.last_result is not None
                seen.append((daemon.loop.last_result.sequence, daemon.loop.last_result.stage_um))
            # down at most the slew limit a cycle (2 µm/s, ≤ 2 periods a cycle); once at
            # the new zero it follows the model's small drift (either way, as small)
            for (qa, a), (qb, b) in itertools.pairwise(seen):
                assert abs(a - b) <= 4.0 * (qb - qa) + 1e-9
                assert b <= a + 1e-9 or abs(b) < 0.5, seen
            assert seen[-1][1] < before - 1.0  # it came down from the old prediction


async def test_rezero_on_a_face_without_an_operator_is_refused(
        sim: ModbusSimController, tmp_path: Path) -> None:
    port = free_tcp_port("127.0.0.1")
    async with face_daemon(tmp_path, sim, _face(port)) as daemon:
        async with await _client(port) as client:
            idx, machine = await _machine(client)
            with pytest.raises(UaStatusCodeError):
                await machine.call_method(f"{idx}:Rezero")
        assert daemon.running.cycle is not None and daemon.running.cycle.models.zero_by is None


async def test_a_face_that_cannot_start_leaves_compensation_running(
        sim: ModbusSimController, tmp_path: Path) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with structlog.testing.capture_logs() as logs:
            async with face_daemon(tmp_path, sim, _face(port)) as daemon:
                before = daemon.telemetry.complete_cycles
                await until(lambda: daemon.telemetry.complete_cycles >= before + 5)
                assert daemon.opcua.face is None
        assert "opcua_face_unavailable" in [e["event"] for e in logs]


@pytest.mark.parametrize(("face", "key_words"), [
    ('policy = "None"\n', "insecure = true"),
    ('policy = "None"\ninsecure = true\nhost = "0.0.0.0"\n', "loopback"),
    ('policy = "Basic256Sha256"\n', "needs certificate and private_key"),
    ('policy = "Basic128Rsa15"\n', "policy"),
    ('policy = "None"\ninsecure = true\noperator_password = "x"\n', "never written"),
])
def test_the_config_refuses_an_unsafe_face_by_name(
        tmp_path: Path, face: str, key_words: str, capsys: pytest.CaptureFixture[str]) -> None:
    path = write_config(tmp_path, "modbus://127.0.0.1:5020")
    path.write_text(path.read_text(encoding="utf-8")
                    + "\n[faces.opcua]\nenabled = true\n" + face, encoding="utf-8")
    assert main(["check", str(path)]) == EX_CONFIG
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "faces.opcua" in err[0] and key_words in err[0], err


INTEROP = Path(__file__).resolve().parents[2] / "interop"


async def test_a_second_stack_node_opcua_reads_and_holds(
        sim: ModbusSimController, tmp_path: Path, pki: Pki) -> None:
    """node-opcua (TypeScript, another OPC UA implementation) against the face:
    Basic256Sha256 SignAndEncrypt with the operator's user name."""
    import json
    import shutil

    node = shutil.which("node")
    if node is None or not (INTEROP / "node_modules" / "node-opcua-client").is_dir():
        pytest.skip("node or node-opcua-client absent (.ci/run installs them: "
                    "npm install --prefix tests/interop)")
    port = free_tcp_port("127.0.0.1")
    async with face_daemon(tmp_path, sim, _face(port, secure=pki)) as daemon:
        proc = await asyncio.create_subprocess_exec(
            node, str(INTEROP / "sethold.mjs"), f"opc.tcp://127.0.0.1:{port}", "test",
            OPERATOR, PASSWORD, str(tmp_path / "node-pki"),
            stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE)
        out, err = await asyncio.wait_for(proc.communicate(), 90.0)
        # node-opcua logs to stdout too: the answer is the last JSON line
        lines = [ln for ln in out.decode(errors="replace").splitlines() if ln.startswith("{")]
        assert lines, (out + err).decode(errors="replace")[-2000:]
        answer = json.loads(lines[-1])
        assert proc.returncode == 0, answer
        assert answer["state"] == "ok" and answer["heartbeat"] >= 1
        assert answer["call"] == "Good" and answer["output"] == [True]
        assert answer["hold"] is True
        assert daemon.running.cycle is not None and daemon.running.cycle.health.operator_hold


def test_a_reload_that_changes_the_face_is_refused_by_name(tmp_path: Path) -> None:
    from compd.runtime.reload import prepare

    port = free_tcp_port("127.0.0.1")
    path = write_config(tmp_path, "modbus://127.0.0.1:5020")
    text = path.read_text(encoding="utf-8")
    path.write_text(text + _face(port), encoding="utf-8")
    old = load_config(path)
    path.write_text(text + _face(port + 1), encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        prepare(old)
    assert info.value.key == "faces.opcua" and "restart" in info.value.reason


async def test_machines_of_one_process_share_one_server(tmp_path: Path) -> None:
    """`compd run DIR`: one endpoint, one object per machine."""
    from compd.runtime.fleet import Fleet, load_machines
    from tests.compd.runtime.test_run_dir import _write_machine

    port = free_tcp_port("127.0.0.1")
    sims = [ModbusSimController() for _ in range(2)]
    d = tmp_path / "machines.d"
    d.mkdir()
    for name, sim in zip(("mill-a", "mill-b"), sims, strict=True):
        await sim.start()
        await sim.publish({"bearing": 20.0, "ambient": 20.0})
        path = _write_machine(d, name, sim.endpoint)
        path.write_text(path.read_text(encoding="utf-8") + _face(port), encoding="utf-8")
    fleet = Fleet(load_machines(d))
    task = asyncio.get_running_loop().create_task(fleet.run())
    try:
        await until(lambda: all(m in fleet.daemons and fleet.daemons[m].opcua.face is not None
                                for m in ("mill-a", "mill-b")))
        async with await _client(port) as client:
            idx = await client.get_namespace_index(NAMESPACE)
            for name in ("mill-a", "mill-b"):
                machine = await client.nodes.objects.get_child(f"{idx}:{name}")
                # each machine its own object (its state is its own business: at 50x
                # with an 8 ms timeout a machine may well be holding now)
                assert await _value(machine, idx, "FaultStateName") in set(FaultState)
                assert await _value(machine, idx, "Model", "Sha256") \
                    == fleet.daemons[name].running.cfg.model_sha256
    finally:
        fleet.request_stop()
        assert await asyncio.wait_for(task, 120.0) == 0
        await release_all()
        for sim in sims:
            await sim.stop()


_COLUMN_MODEL = """
[model]
name = "spindle and column"
period_s = 1.0

[[terms]]
name = "spindle"
inputs = { bearing = 1.0 }
a = ["16.0005", "-15.9975", "0"]
b = ["1", "-0.99983", "0", "0"]

[[terms]]
name = "column"
inputs = { column = 1.0 }
a = ["0.5", "0"]
b = ["1", "-0.9"]
"""

_COLUMN_CHANNEL = """
[channels.column]
address = { kind = "input", address = 2, type = "int16", scale = 0.1 }
unit = "degC"
range = [-20.0, 150.0]

[model]"""


async def _names(folder: Node) -> set[str]:
    return {(await n.read_browse_name()).Name for n in await folder.get_children()}


async def test_a_reload_that_changes_the_model_is_published_by_the_face(
        sim: ModbusSimController, tmp_path: Path) -> None:
    """After a SIGHUP reload to another model on another channel set, the face's
    Terms, Channels and Model are the new model's, and it publishes their values."""
    port = free_tcp_port("127.0.0.1")
    await sim.publish({"column": 20.0})
    async with face_daemon(tmp_path, sim, _face(port)) as daemon:
        client = await _client(port)
        async with client:
            idx, machine = await _machine(client)
            terms = await machine.get_child(f"{idx}:Terms")
            channels = await machine.get_child(f"{idx}:Channels")
            assert await _names(terms) == {"spindle_um", "ambient_um"}
            (tmp_path / "column.toml").write_text(_COLUMN_MODEL, encoding="utf-8")
            path = daemon.running.cfg.path
            text = path.read_text(encoding="utf-8")
            path.write_text(text.replace('file = "sp2"', 'file = "column.toml"')
                            .replace("[model]", _COLUMN_CHANNEL), encoding="utf-8")
            daemon.request_reload()
            await until(lambda: daemon.reloader.reloads >= 1)
            assert daemon.running.cfg.model.name == "spindle and column"
            await _becomes(machine, idx, ("Model", "Name"), "spindle and column")
            assert await _value(machine, idx, "Model", "Sha256") == daemon.running.cfg.model_sha256
            assert await _names(terms) == {"spindle_um", "column_um"}
            assert await _names(channels) == {"bearing", "ambient", "column"}
            await sim.publish({"column": 21.0})
            await _becomes(machine, idx, ("Channels", "column", "Value"), 21.0)
            await _becomes(machine, idx, ("Channels", "column", "Valid"), True)
            for _ in range(12_000):  # the new term's contribution, once stepped
                column = await _value(machine, idx, "Terms", "column_um")
                if isinstance(column, float) and not math.isnan(column):
                    break
                await asyncio.sleep(0.01)
            assert isinstance(column, float) and not math.isnan(column)
