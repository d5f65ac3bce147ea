"""One asyncua server on a (host, port) that the OPC UA faces of a process share, one
object per machine: its own event loop on its own thread, its guard on connections and
sessions, its start (certificate, policy, users, the CompdFaultState type) and stop.
What the face publishes is `compd.faces.opcua_face`."""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import structlog
from asyncua import ua
from asyncua.server.server import Server

from compd.config.loader import credential_path
from compd.core.faults import FaultState
from compd.errors import ConfigError
from compd.faces.opcua_access import POLICIES, ReadOnlyRules, Users
from compd.faces.opcua_guard_report import quiet_asyncua_faults
from compd.faces.opcua_limits import ACCEPT_BURST, FaceLoop, Guard
from compd.faces.opcua_shape import MachineNodes
from drivers.opcua_space import CopiedSpaceInternalServer

if TYPE_CHECKING:
    from asyncua.common.node import Node

    from compd.config.schema import OpcUaFaceSection

#: the face's namespace URI
NAMESPACE = "urn:compd"
#: the FaultState enumeration's values, in this order
FAULT_STATES: tuple[FaultState, ...] = tuple(FaultState)

@dataclass
class FaceMachine:
    """One machine's object and the nodes the face writes."""

    name: str
    obj: Node
    nodes: dict[str, Node] = field(default_factory=dict)
    hold: Callable[[bool, str], bool] | None = None
    #: the config's part of the object (terms, channels, model, adaptation)
    shape: MachineNodes | None = None


class SharedServer:
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
        self.machines: dict[str, FaceMachine] = {}
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
        users = Users(sec.operator, password, anonymous, self.guard)
        server = Server(iserver=CopiedSpaceInternalServer(user_manager=users))
        await server.init()
        # the guard limits connections; asyncua's own cap is only a backstop above it (an
        # evicted connection leaves asyncua's list just after its place is given to the
        # new one), and its watchdog would log each idle connection
        server.iserver.max_connections = self.guard.limit + ACCEPT_BURST
        server.iserver.max_pending_activation_seconds = 0
        server.disable_clock()
        server.set_endpoint(f"opc.tcp://{url_host(sec.host)}:{sec.port}")
        server.set_server_name("compd")
        await server.set_application_uri("urn:compd:server")
        if sec.policy != "None":
            assert sec.certificate is not None and sec.private_key is not None
            await server.load_certificate(str(self._path(sec.certificate)))
            await server.load_private_key(str(self._path(sec.private_key)))
        # asyncua annotates the ruleset as its SimpleRoleRuleset class, though it only calls
        # check_validity (the PermissionRuleset interface) that ReadOnlyRules implements
        server.set_security_policy([POLICIES[sec.policy]],
                                   permission_ruleset=ReadOnlyRules(self))  # type: ignore[arg-type]
        # no user name over an unencrypted channel: policy None is anonymous only
        tokens: list[type] = [] if sec.policy == "None" else [ua.UserNameIdentityToken]
        if anonymous:
            tokens.append(ua.AnonymousIdentityToken)
        server.set_identity_tokens(tokens)
        self.idx = await server.register_namespace(NAMESPACE)
        self.fault_type = await fault_state_type(server, self.idx)
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


def url_host(host: str) -> str:
    return f"[{host}]" if ":" in host else host


async def fault_state_type(server: Server, idx: int) -> ua.NodeId:
    """The CompdFaultState enumeration data type (names for FaultState's values)."""
    from asyncua.common.structures104 import new_enum

    node = await new_enum(server, idx, "CompdFaultState", [s.value for s in FAULT_STATES])
    await server.load_data_type_definitions()
    return node.nodeid

