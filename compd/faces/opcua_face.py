"""compd's own OPC UA server (``[faces.opcua]``): what it does, for the PLC and SCADA.

Namespace ``urn:compd``; under Objects one object per machine, named after
``[machine] name``:

- ``Offset_um`` (what the controller holds: the last confirmed offset),
  ``ModelOutput_um``, ``Terms/<term>_um`` (each term's contribution),
  ``FaultState`` (an enumeration, data type ``CompdFaultState``: 0 init,
  1 ok, 2 hold, 3 ramp, 4 shutdown, 5 stopped, 6 held, 7 write_fault) and
  ``FaultStateName``,
  ``Cause`` (why the offset compd wants is not in force: ``in_force``,
  ``operator_hold``, ``inputs_invalid``, ``model_worse_than_none``, ...;
  `compd.core.health.Cause`) and ``OffsetInForce`` (true for ``in_force``
  and ``operator_hold``: what `compd health` calls healthy),
  ``StatusWord`` (the status bits written to the controller), ``Heartbeat``,
  ``OperatorHold``, ``Channels/<name>/Value`` and ``/Valid``, ``Model/Name``
  and ``Model/Sha256``, and with ``[adaptation]`` ``Adaptation/Bias_um``,
  ``Adaptation/BiasSigma_um``, ``Adaptation/Correction_um``;
- the method ``SetHold(Boolean)``: true switches compensation to hold (the
  offset stays where it is; faults still hold and ramp as always), false
  releases it (the offset slews back to the model at the slew limit);
- the method ``Rezero()``: the present prediction becomes the new zero (at
  tool touch-off; the offset ramps to the new target at the slew limit, the
  re-zero is checkpointed and survives a restart); returns whether the daemon
  took it. ``Cause`` ``waiting_for_permission`` and ``PendingOffset_um`` tell a
  change held back for ``[output] update_permitted``.
  Only the configured ``operator`` may call either method; every call, allowed
  or refused, is logged with the user, the client's address and what was
  asked.

Everything else is read-only for every client: writes, node management and
history updates are refused (BadUserAccessDenied) by the permission rules.
By default the endpoint is Basic256Sha256 (SignAndEncrypt) with the
server's certificate, and clients authenticate with a user name (the
operator) unless ``anonymous_read``; policy None only with ``insecure =
true`` on a loopback host (the config refuses anything else).

The loop never waits for the face: the server runs on a thread of its own,
with its own event loop (``compd-opcua-face``), so that its start (the
first server of a process builds the standard address space, about a second
of CPU; later ones copy it, `drivers.opcua_space`) and its clients never
hold the daemon's loop; `publish` hands the cycle's snapshot over and the
face's task writes it into the address space. SetHold runs on the face's
thread and hands the hold to the daemon's loop, where the cycle lives. A
face that cannot start (a port in use, a bad certificate) is logged
(``opcua_face_unavailable``) and compensation runs without it; an error
while publishing is logged once (``opcua_face_failed``) and the face
keeps trying. Machines of one process (`compd run DIR`) that name the same
host and port share one server, one object each.

Limits (`compd.faces.opcua_limits`): ``max_connections`` TCP connections
(fewer when RLIMIT_NOFILE leaves less beside a reserve for the cycle); at the
limit a new connection evicts the one that has waited longest for its
handshake (silent ones first), and is closed at once only when every other
has a session or was just accepted; ``max_sessions`` sessions, of which
anonymous readers leave ``reserved_sessions`` to the operator; a connection
without a session after ``handshake_timeout_s`` closed; failed logins logged
with the user and the peer, rate-limited, and counted in metrics. So sockets
that say nothing, or anonymous readers, never keep the operator from SetHold.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import math
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import structlog
from asyncua import ua
from asyncua.crypto.permission_rules import PermissionRuleset, User, UserRole
from asyncua.server.server import Server
from asyncua.server.user_managers import UserManager
from asyncua.ua.object_ids import ObjectIds

from compd.config.loader import credential_path
from compd.core.faults import FaultState
from compd.errors import ConfigError
from compd.faces.opcua_limits import (
    ACCEPT_BURST,
    FaceLoop,
    Guard,
    GuardCollector,
    quiet_asyncua_faults,
)
from compd.faces.opcua_shape import MachineNodes
from drivers.opcua_space import CopiedSpaceInternalServer

if TYPE_CHECKING:
    from asyncua.common.node import Node
    from asyncua.server.internal_server import InternalServer
    from prometheus_client import CollectorRegistry

    from compd.config.loader import LoadedConfig
    from compd.config.schema import OpcUaFaceSection
    from compd.core.plan import Row

__all__ = ["NAMESPACE", "OpcUaFace", "published_values", "release_all"]

NAMESPACE = "urn:compd"
#: the FaultState enumeration's values, in this order
FAULT_STATES: tuple[FaultState, ...] = tuple(FaultState)

_POLICIES = {
    "Basic256Sha256": ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt,
    "Aes128_Sha256_RsaOaep": ua.SecurityPolicyType.Aes128Sha256RsaOaep_SignAndEncrypt,
    "Aes256_Sha256_RsaPss": ua.SecurityPolicyType.Aes256Sha256RsaPss_SignAndEncrypt,
    "None": ua.SecurityPolicyType.NoSecurity,
}
#: requests any client may make once its session is up (reading, browsing, subscribing)
_READ_REQUESTS = frozenset(ua.NodeId(ua.Int32(i)) for i in (
    ObjectIds.CreateSessionRequest_Encoding_DefaultBinary,
    ObjectIds.CloseSessionRequest_Encoding_DefaultBinary,
    ObjectIds.ActivateSessionRequest_Encoding_DefaultBinary,
    ObjectIds.ReadRequest_Encoding_DefaultBinary,
    ObjectIds.BrowseRequest_Encoding_DefaultBinary,
    ObjectIds.BrowseNextRequest_Encoding_DefaultBinary,
    ObjectIds.GetEndpointsRequest_Encoding_DefaultBinary,
    ObjectIds.FindServersRequest_Encoding_DefaultBinary,
    ObjectIds.TranslateBrowsePathsToNodeIdsRequest_Encoding_DefaultBinary,
    ObjectIds.RegisterNodesRequest_Encoding_DefaultBinary,
    ObjectIds.UnregisterNodesRequest_Encoding_DefaultBinary,
    ObjectIds.CreateSubscriptionRequest_Encoding_DefaultBinary,
    ObjectIds.ModifySubscriptionRequest_Encoding_DefaultBinary,
    ObjectIds.DeleteSubscriptionsRequest_Encoding_DefaultBinary,
    ObjectIds.SetPublishingModeRequest_Encoding_DefaultBinary,
    ObjectIds.CreateMonitoredItemsRequest_Encoding_DefaultBinary,
    ObjectIds.ModifyMonitoredItemsRequest_Encoding_DefaultBinary,
    ObjectIds.DeleteMonitoredItemsRequest_Encoding_DefaultBinary,
    ObjectIds.SetMonitoringModeRequest_Encoding_DefaultBinary,
    ObjectIds.PublishRequest_Encoding_DefaultBinary,
    ObjectIds.RepublishRequest_Encoding_DefaultBinary,
    ObjectIds.TransferSubscriptionsRequest_Encoding_DefaultBinary,
))
_CALL_REQUEST = ua.NodeId(ua.Int32(ObjectIds.CallRequest_Encoding_DefaultBinary))

#: running servers of this process by (host, port): machines of one process share one
_SERVERS: dict[tuple[str, int], _SharedServer] = {}


class _Users(UserManager):
    """The operator with its password; anonymous readers when allowed. Failed
    logins and sessions over the limit go to the guard (it knows the peer)."""

    def __init__(self, operator: str | None, password: str | None, anonymous: bool,
                 guard: Guard) -> None:
        self.operator, self._password, self.anonymous = operator, password, anonymous
        self.guard = guard

    def get_user(self, iserver: InternalServer, username: str | None = None,
                 password: str | None = None, certificate: Any = None) -> User | None:
        user: User | None = None
        if username is None:
            user = User(role=UserRole.Anonymous) if self.anonymous else None
        elif self.operator is not None and username == self.operator \
                and password is not None and password == self._password:
            user = User(role=UserRole.User, name=username)
        if user is None:
            self.guard.login_failed("anonymous" if username is None else username)
        else:  # BadTooManySessions over the limit (the anonymous share, for anonymous)
            self.guard.login_ok(username or "anonymous", anonymous=username is None)
        return user


class _ReadOnlyRules(PermissionRuleset):
    """Reading for every session; a Call only for the operator; nothing else."""

    def __init__(self, shared: _SharedServer) -> None:
        self.shared = shared

    def check_validity(self, user: Any, action_type_id: Any, body: Any) -> bool:
        if action_type_id in _READ_REQUESTS:
            return True
        if action_type_id == _CALL_REQUEST:
            allowed = user is not None and self.shared.operator is not None \
                and user.name == self.shared.operator
            self.shared.note_call(user, allowed)
            return allowed
        return False


@dataclass
class _Machine:
    """One machine's object and the nodes the face writes."""

    name: str
    obj: Node
    nodes: dict[str, Node] = field(default_factory=dict)
    hold: Callable[[bool, str], bool] | None = None
    #: the config's part of the object (terms, channels, model, adaptation)
    shape: MachineNodes | None = None


class _SharedServer:
    """One asyncua server on (host, port), with one object per machine."""

    def __init__(self, section: OpcUaFaceSection, base: Path) -> None:
        self.section = section
        self.base = base
        self.operator = section.operator
        self.server: Server | None = None
        # sessions are kept back from anonymous readers only for an operator to use
        self.guard = Guard(max_connections=section.max_connections,
                           max_sessions=section.max_sessions,
                           reserved_sessions=section.reserved_sessions
                           if section.operator is not None else 0,
                           handshake_timeout_s=section.handshake_timeout_s)
        self._summaries: asyncio.Task[None] | None = None
        #: the face's own event loop, on its own thread (see the module docstring);
        #: the servers it starts accept through the guard
        self.loop: asyncio.AbstractEventLoop = FaceLoop(self.guard)
        self._thread = threading.Thread(target=self._run_loop, name="compd-opcua-face",
                                        daemon=True)
        self._closing = False
        self.idx = 0
        self.machines: dict[str, _Machine] = {}
        self.fault_type: ua.NodeId | None = None
        #: who the last Call came from (set by the permission check just before it runs)
        self.caller: tuple[str, str] = ("anonymous", "unknown")
        self.log = structlog.get_logger("compd")
        self._thread.start()
        # start() runs on the face's thread and sets idx and fault_type: it is
        # submitted last, once nothing here can overwrite what it sets
        #: done when the server is up (or failed): machines starting meanwhile wait on it
        self.started: concurrent.futures.Future[None] = self.submit(self.start())

    def _run_loop(self) -> None:
        asyncio.set_event_loop(self.loop)
        self.loop.run_forever()

    def submit(self, coro: Any) -> concurrent.futures.Future[Any]:
        """Run `coro` on the face's loop (from any thread)."""
        return asyncio.run_coroutine_threadsafe(coro, self.loop)

    def close(self) -> None:
        """Stop the server and the face's loop and thread (from another thread); once."""
        if self._closing:
            return
        self._closing = True
        with contextlib.suppress(Exception):
            self.submit(self.stop()).result(timeout=10.0)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self._thread.join(timeout=10.0)
        if not self._thread.is_alive():
            self.loop.close()

    def note_call(self, user: Any, allowed: bool) -> None:
        name = getattr(user, "name", None) or "anonymous"
        peer = "unknown"
        server = self.server
        if server is not None:
            for session in list(getattr(server.iserver, "_external_sessions", {}).values()):
                if session.user is user:
                    peer = str(session.name)
        self.caller = (name, peer)
        if not allowed:
            self.log.warning("opcua_call_refused", user=name, peer=peer,
                             reason="only the configured operator may call methods")

    async def start(self) -> None:
        sec = self.section
        password = None
        if sec.operator_password_file is not None:
            pf = credential_path(sec.operator_password_file, self.base)
            try:
                password = pf.read_text(encoding="utf-8").strip("\r\n")
            except OSError as exc:
                raise ConfigError("faces.opcua.operator_password_file",
                                  f"cannot read {pf} ({exc.strerror})") from None
        anonymous = sec.anonymous_read or sec.policy == "None"
        self.guard.fit_to_descriptors()  # ValueError: not one descriptor to spare
        quiet_asyncua_faults()
        # the standard address space is a copy of the one this process built first
        # (drivers.opcua_space), not filled node by node again for every server
        users = _Users(sec.operator, password, anonymous, self.guard)
        server = Server(iserver=CopiedSpaceInternalServer(user_manager=users))
        await server.init()
        # the guard limits connections; asyncua's own cap is only a backstop above it (an
        # evicted connection leaves asyncua's list just after its place is given to the
        # new one), and its watchdog would log each idle connection
        server.iserver.max_connections = self.guard.limit + ACCEPT_BURST
        server.iserver.max_pending_activation_seconds = 0
        server.disable_clock()
        server.set_endpoint(f"opc.tcp://{_url_host(sec.host)}:{sec.port}")
        server.set_server_name("compd")
        await server.set_application_uri("urn:compd:server")
        if sec.policy != "None":
            assert sec.certificate is not None and sec.private_key is not None
            await server.load_certificate(str(self._path(sec.certificate)))
            await server.load_private_key(str(self._path(sec.private_key)))
        # asyncua annotates the ruleset as its SimpleRoleRuleset class, though it only calls
        # check_validity (the PermissionRuleset interface) that _ReadOnlyRules implements
        server.set_security_policy([_POLICIES[sec.policy]],
                                   permission_ruleset=_ReadOnlyRules(self))  # type: ignore[arg-type]
        # no user name over an unencrypted channel: policy None is anonymous only
        tokens: list[type] = [] if sec.policy == "None" else [ua.UserNameIdentityToken]
        if anonymous:
            tokens.append(ua.AnonymousIdentityToken)
        server.set_identity_tokens(tokens)
        self.idx = await server.register_namespace(NAMESPACE)
        self.fault_type = await _fault_state_type(server, self.idx)
        await server.start()
        self.server = server
        self._summaries = asyncio.get_running_loop().create_task(self.guard.summarise(),
                                                                 name="opcua-face-summaries")

    def _path(self, p: Path) -> Path:
        return p if p.is_absolute() else self.base / p

    async def stop(self) -> None:
        summaries, self._summaries = self._summaries, None
        if summaries is not None:
            summaries.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await summaries
        self.guard.flush(force=True)  # what the last minute did not tell yet
        server, self.server = self.server, None
        if server is not None:
            await server.stop()


def _url_host(host: str) -> str:
    return f"[{host}]" if ":" in host else host


async def _fault_state_type(server: Server, idx: int) -> ua.NodeId:
    """The CompdFaultState enumeration data type (names for FaultState's values)."""
    from asyncua.common.structures104 import new_enum

    node = await new_enum(server, idx, "CompdFaultState", [s.value for s in FAULT_STATES])
    await server.load_data_type_definitions()
    return node.nodeid


class OpcUaFace:
    """One machine's part of the OPC UA face (see the module docstring)."""

    def __init__(self, cfg: LoadedConfig, hold: Callable[[bool, str], bool],
                 registry: CollectorRegistry | None = None, *,
                 rezero: Callable[[str], bool] | None = None) -> None:
        self.cfg = cfg
        self._rezero = rezero
        #: where the face's counts (connections, refusals, failed logins) are served
        self.registry = registry
        self._collector: GuardCollector | None = None
        self.section = cfg.raw.faces.opcua
        self.name = cfg.raw.machine.name
        self._hold = hold
        self._shared: _SharedServer | None = None
        self._machine: _Machine | None = None
        self._pending: dict[str, Any] | None = None
        self._wake: asyncio.Event | None = None  # on the face's loop
        self._task: asyncio.Task[None] | None = None
        self._daemon_loop: asyncio.AbstractEventLoop | None = None
        self._failed = False
        #: the config the machine's object has the nodes of (the face's task makes them
        #: match `cfg` before it writes the next values)
        self._shaped: LoadedConfig | None = None
        self.log = structlog.get_logger("compd").bind(face="opcua")

    @property
    def endpoint(self) -> str:
        return f"opc.tcp://{_url_host(self.section.host)}:{self.section.port}"

    async def start(self) -> bool:
        """Start (or join) the server and add this machine's object; False (logged)
        when it cannot: compensation runs without the face."""
        key = (self.section.host, self.section.port)
        self._daemon_loop = asyncio.get_running_loop()
        shared = _SERVERS.get(key)
        if shared is None:
            shared = _SERVERS[key] = _SharedServer(self.section, self.cfg.path.parent)
        elif shared.section != self.section:
            self.log.warning("opcua_face_shared", endpoint=self.endpoint,
                             reason="another machine's [faces.opcua] settings serve it")
        try:
            await asyncio.wrap_future(shared.started)
            self._machine = await asyncio.wrap_future(shared.submit(self._add_machine(shared)))
            self._task = await asyncio.wrap_future(shared.submit(self._start_publisher()))
        except Exception as exc:  # a port in use, a bad certificate: never the cycle's end
            self.log.error("opcua_face_unavailable", endpoint=self.endpoint,
                           error=str(exc) or type(exc).__name__)
            if not shared.machines and _SERVERS.get(key) is shared:
                _SERVERS.pop(key, None)
                await asyncio.to_thread(shared.close)
            return False
        self._shared = shared
        if self.registry is not None:
            self._collector = GuardCollector(shared.guard)
            self.registry.register(self._collector)
        self.log.info("opcua_face_started", endpoint=self.endpoint, policy=self.section.policy,
                      machine=self.name, max_connections=shared.guard.limit)
        return True

    async def _add_machine(self, shared: _SharedServer) -> _Machine:
        server, idx = shared.server, shared.idx
        assert server is not None
        if self.name in shared.machines:
            raise RuntimeError(f"a machine named {self.name!r} is already served")
        cfg = self.cfg
        obj = await server.nodes.objects.add_object(
            ua.NodeId(ua.String(f"{self.name}.Machine"), ua.Int16(idx)),
            ua.QualifiedName(self.name, idx))
        m = _Machine(self.name, obj, hold=self._hold)
        at = MachineNodes(server, idx, self.name, obj, m.nodes)
        var = at.var
        nan = math.nan
        await var(obj, "Offset_um", "Offset_um", nan, ua.VariantType.Double)
        await var(obj, "ModelOutput_um", "ModelOutput_um", nan, ua.VariantType.Double)
        await var(obj, "FaultState", "FaultState", FAULT_STATES.index(FaultState.INIT),
                  ua.VariantType.Int32, shared.fault_type)
        await var(obj, "FaultStateName", "FaultStateName", FaultState.INIT.value,
                  ua.VariantType.String)
        await var(obj, "Cause", "Cause", "starting", ua.VariantType.String)
        await var(obj, "OffsetInForce", "OffsetInForce", False, ua.VariantType.Boolean)
        await var(obj, "StatusWord", "StatusWord", 0, ua.VariantType.UInt32)
        await var(obj, "Heartbeat", "Heartbeat", 0, ua.VariantType.UInt32)
        await var(obj, "OperatorHold", "OperatorHold", False, ua.VariantType.Boolean)
        await var(obj, "PendingOffset_um", "PendingOffset_um", nan, ua.VariantType.Double)
        for folder in ("Terms", "Channels", "Model"):
            await at.folder(obj, folder, folder)
        await at.shape(cfg)  # the terms, channels, model and adaptation of the config
        self._shaped = cfg
        await obj.add_method(at.nid("SetHold"), ua.QualifiedName("SetHold", idx),
                             self._set_hold(shared), [ua.VariantType.Boolean],
                             [ua.VariantType.Boolean])
        await obj.add_method(at.nid("Rezero"), ua.QualifiedName("Rezero", idx),
                             self._rezero_call(shared), [], [ua.VariantType.Boolean])
        m.shape = at
        shared.machines[self.name] = m
        return m

    async def _start_publisher(self) -> asyncio.Task[None]:
        self._wake = asyncio.Event()
        return asyncio.get_running_loop().create_task(self._publisher(),
                                                      name=f"opcua-face:{self.name}")

    def _set_hold(self, shared: _SharedServer) -> Callable[..., Any]:
        async def on_daemon_loop(on: bool, user: str) -> bool:
            return self._hold(on, user)

        async def call(parent: ua.NodeId, hold: ua.Variant | bool) -> list[ua.Variant]:
            on = bool(hold.Value if isinstance(hold, ua.Variant) else hold)
            user, peer = shared.caller
            loop = self._daemon_loop
            done = False
            if loop is not None and not loop.is_closed():  # the cycle lives on that loop
                done = await asyncio.wrap_future(asyncio.run_coroutine_threadsafe(
                    on_daemon_loop(on, user), loop))
            self.log.warning("opcua_set_hold", machine=self.name, hold=on, user=user,
                             peer=peer, applied=done)
            return [ua.Variant(done, ua.VariantType.Boolean)]
        return call

    def _rezero_call(self, shared: _SharedServer) -> Callable[..., Any]:
        async def on_daemon_loop(user: str, peer: str) -> bool:
            return self._rezero is not None and self._rezero(f"opcua: {user} from {peer}")

        async def call(parent: ua.NodeId) -> list[ua.Variant]:
            user, peer = shared.caller
            loop = self._daemon_loop
            done = False
            if loop is not None and not loop.is_closed():  # the cycle lives on that loop
                done = await asyncio.wrap_future(asyncio.run_coroutine_threadsafe(
                    on_daemon_loop(user, peer), loop))
            self.log.warning("opcua_rezero", machine=self.name, user=user, peer=peer,
                             applied=done)
            return [ua.Variant(done, ua.VariantType.Boolean)]
        return call

    def reconfigure(self, cfg: LoadedConfig) -> None:
        """A reloaded config: from the next `publish` on, the face shows its terms,
        channels, model and adaptation (`compd.faces.opcua_shape`); the face's task
        makes the nodes match before it writes the values."""
        self.cfg = cfg

    def publish(self, result: Row) -> None:
        """The committed row for the face's task (cheap; never raises, never waits)."""
        if self._machine is None:
            return
        values = published_values(result, self.cfg)
        self._pending = values
        shared, wake = self._shared, self._wake
        if shared is not None and wake is not None:
            shared.loop.call_soon_threadsafe(wake.set)

    async def _publisher(self) -> None:
        wake = self._wake
        assert wake is not None
        while True:
            await wake.wait()
            wake.clear()
            values, self._pending = self._pending, None
            if values is None or self._machine is None:
                continue
            try:
                cfg, shape = self.cfg, self._machine.shape
                if cfg is not self._shaped and shape is not None:
                    await shape.shape(cfg)  # a reload: the new config's nodes first
                    self._shaped = cfg
                for path, (value, vtype) in values.items():
                    node = self._machine.nodes.get(path)
                    if node is not None:
                        await node.write_value(ua.DataValue(ua.Variant(value, vtype)))
                if self._failed:
                    self._failed = False
                    self.log.info("opcua_face_recovered")
            except Exception as exc:  # the face's trouble, never the cycle's
                if not self._failed:
                    self._failed = True
                    self.log.error("opcua_face_failed", error=str(exc) or type(exc).__name__)

    async def stop(self) -> None:
        collector, self._collector = self._collector, None
        if collector is not None and self.registry is not None:
            with contextlib.suppress(KeyError):
                self.registry.unregister(collector)
        shared, self._shared = self._shared, None
        if shared is None:
            return
        with contextlib.suppress(Exception):
            await asyncio.wrap_future(shared.submit(self._leave(shared)))
        if not shared.machines:
            _SERVERS.pop((shared.section.host, shared.section.port), None)
            await asyncio.to_thread(shared.close)

    async def _leave(self, shared: _SharedServer) -> None:
        """On the face's loop: this machine's task and object go."""
        task, self._task = self._task, None
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        m, self._machine = self._machine, None
        if m is not None and shared.machines.pop(m.name, None) is not None \
                and shared.server is not None:
            with contextlib.suppress(Exception):
                await shared.server.delete_nodes([m.obj], recursive=True)


async def release_all() -> None:
    """Stop every face server of this process (tests)."""
    for key, shared in list(_SERVERS.items()):
        _SERVERS.pop(key, None)
        await asyncio.to_thread(shared.close)


def _num(x: float | None) -> float:
    return math.nan if x is None or not isinstance(x, int | float) else float(x)


def published_values(result: Row, cfg: LoadedConfig) -> dict[str, tuple[Any, ua.VariantType]]:
    """What the face writes for one cycle's report: node path -> (value, type).
    ``Offset_um`` is the offset the controller confirmed (`Row.confirmed_um`),
    ``OffsetInForce`` the cause's verdict (`Row.healthy`)."""
    snap = result.snapshot
    values: dict[str, tuple[Any, ua.VariantType]] = {
        "Offset_um": (_num(result.confirmed_um), ua.VariantType.Double),
        "ModelOutput_um": (_num(result.model_um), ua.VariantType.Double),
        "FaultState": (FAULT_STATES.index(result.state), ua.VariantType.Int32),
        "FaultStateName": (result.state.value, ua.VariantType.String),
        "Cause": (result.cause.value, ua.VariantType.String),
        "OffsetInForce": (result.healthy, ua.VariantType.Boolean),
        "StatusWord": (int(result.status), ua.VariantType.UInt32),
        "Heartbeat": (int(result.heartbeat), ua.VariantType.UInt32),
        "OperatorHold": (bool(snap.operator_hold), ua.VariantType.Boolean),
        "PendingOffset_um": (_num(snap.pending_um), ua.VariantType.Double),
    }
    for term in cfg.model.terms:
        values[f"Terms.{term.name}"] = (_num(result.contributions.get(term.name)),
                                        ua.VariantType.Double)
    for ch in cfg.channels:
        values[f"Channels.{ch}.Value"] = (_num(result.channels.get(ch)), ua.VariantType.Double)
        values[f"Channels.{ch}.Valid"] = (result.validity.get(ch) is None,
                                          ua.VariantType.Boolean)
    if snap.adaptation is not None:
        est = snap.adaptation
        values["Adaptation.Bias_um"] = (est.bias_um, ua.VariantType.Double)
        values["Adaptation.BiasSigma_um"] = (est.bias_sigma_um, ua.VariantType.Double)
        values["Adaptation.Correction_um"] = (est.correction_um, ua.VariantType.Double)
    return values
