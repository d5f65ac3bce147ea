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
  ``Adaptation/BiasSigma_um``, ``Adaptation/Correction_um``; with
  ``[output.axes]`` one folder per axis, ``Axes/X`` (``Y``, ``Z``):
  ``Value_um`` and ``Slope_um_m`` (the line the controller confirmed),
  ``ValueModel_um`` and ``SlopeModel_um_m`` (what the axis's models ask),
  ``InForce``, ``FaultStateName``, ``Cause``, ``StatusWord`` (the axis's own
  bits, as ``StatusWord``'s), ``ReferencePosition_mm``, and ``Position_mm`` and
  ``Offset_um`` (an axis written as one offset at its read position: that
  position and the offset sent at it; NaN otherwise);
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

The shared server is `compd.faces.opcua_shared`, who may do what
`compd.faces.opcua_access`; this module is one machine's object and what it publishes.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import structlog
from asyncua import ua

from compd.core.faults import FaultState
from compd.faces.opcua_guard_report import GuardCollector
from compd.faces.opcua_shape import AXIS_VARIABLES, MachineNodes, axis_path
from compd.faces.opcua_shared import FAULT_STATES, NAMESPACE, FaceMachine, SharedServer, url_host

if TYPE_CHECKING:
    from prometheus_client import CollectorRegistry

    from compd.config.loader import LoadedConfig
    from compd.core.plan import Row

__all__ = ["NAMESPACE", "OpcUaFace", "published_values", "release_all"]

#: running servers of this process by (host, port): machines of one process share one
_SERVERS: dict[tuple[str, int], SharedServer] = {}


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
        self._shared: SharedServer | None = None
        self._machine: FaceMachine | None = None
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
        return f"opc.tcp://{url_host(self.section.host)}:{self.section.port}"

    async def start(self) -> bool:
        """Start (or join) the server and add this machine's object; False (logged)
        when it cannot: compensation runs without the face."""
        key = (self.section.host, self.section.port)
        self._daemon_loop = asyncio.get_running_loop()
        shared = _SERVERS.get(key)
        if shared is None:
            shared = _SERVERS[key] = SharedServer(self.section, self.cfg.path.parent)
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

    async def _add_machine(self, shared: SharedServer) -> FaceMachine:
        server, idx = shared.server, shared.idx
        assert server is not None
        if self.name in shared.machines:
            raise RuntimeError(f"a machine named {self.name!r} is already served")
        cfg = self.cfg
        obj = await server.nodes.objects.add_object(
            ua.NodeId(ua.String(f"{self.name}.Machine"), ua.Int16(idx)),
            ua.QualifiedName(self.name, idx))
        m = FaceMachine(self.name, obj, hold=self._hold)
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

    async def _on_daemon_loop(self, request: Callable[[], bool]) -> bool:
        """`request()` run on the daemon's loop, where the cycle lives (the server
        may run on another thread's); False when that loop is gone."""
        async def run() -> bool:
            return request()

        loop = self._daemon_loop
        if loop is None or loop.is_closed():
            return False
        return await asyncio.wrap_future(asyncio.run_coroutine_threadsafe(run(), loop))

    def _set_hold(self, shared: SharedServer) -> Callable[..., Any]:
        async def call(parent: ua.NodeId, hold: ua.Variant | bool) -> list[ua.Variant]:
            on = bool(hold.Value if isinstance(hold, ua.Variant) else hold)
            user, peer = shared.caller
            done = await self._on_daemon_loop(lambda: self._hold(on, user))
            self.log.warning("opcua_set_hold", machine=self.name, hold=on, user=user,
                             peer=peer, applied=done)
            return [ua.Variant(done, ua.VariantType.Boolean)]
        return call

    def _rezero_call(self, shared: SharedServer) -> Callable[..., Any]:
        async def call(parent: ua.NodeId) -> list[ua.Variant]:
            user, peer = shared.caller
            rezero = self._rezero
            done = rezero is not None and await self._on_daemon_loop(
                lambda: rezero(f"opcua: {user} from {peer}"))
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

    async def _leave(self, shared: SharedServer) -> None:
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
    for axis, line in result.axes.items():
        axis_values = {
            "Value_um": _num(line.value.confirmed), "Slope_um_m": _num(line.slope.confirmed),
            "ValueModel_um": _num(line.value.model), "SlopeModel_um_m": _num(line.slope.model),
            "InForce": bool(line.in_force), "FaultStateName": line.state.value,
            "Cause": line.cause.value, "StatusWord": int(line.status),
            "ReferencePosition_mm": _num(line.reference_mm),
            "Position_mm": _num(line.position_mm), "Offset_um": _num(line.offset_um)}
        for name, value in axis_values.items():
            values[axis_path(axis, name)] = (value, AXIS_VARIABLES[name])
    return values
