"""A simulated controller speaking OPC UA: a real asyncua server on 127.0.0.1.

Address space (namespace ``urn:compd:sim``, string NodeIds ``Machine.<name>``):

- every standard channel (`drivers.sim.CHANNELS`), read-only for clients (writable
  with `writable_channels=True`, for a HIL bench whose plant writes them);
  temperatures and most values are ``Double``, ``power_kw`` is ``Float``;
- writable outputs ``offset`` (``Float``), ``heartbeat`` (``UInt32``),
  ``status`` (``UInt16``);
- writable encoding nodes (``enc_*``: Int16, Int32, Int64, Double, Float) used
  by the contract tests;
- per axis X, Y, Z the SINUMERIK temperature-compensation setting data as
  writable ``Double`` nodes ``Machine.<AXIS>.$SA_TEMP_COMP_ABS_VALUE`` (SD43900,
  mm), ``...$SA_TEMP_COMP_SLOPE`` (SD43910, tan β) and
  ``...$SA_TEMP_COMP_REF_POSITION`` (SD43920, mm) (`drivers.sim.temp_comp`;
  their addresses with compd's scales in `temp_comp`); `compensation(axis)` is
  the line in force;
- a channel's former name (``Machine.speed_rpm``, `drivers.sim.renamed`), read-only,
  holding what its current node holds, so that a config written before the
  rename still reads; the first client Read of it says once, on stderr, to use
  the current node.

Test hooks: `publish_status` puts a channel in a Bad/Uncertain state (an open
sensor), `set_latency` delays every client Read/Write (a hung controller),
`read_requests` counts client Read requests touching this namespace, `restart`
drops every connection and rebinds the same port with outputs forgotten,
`set_write_access` takes CurrentWrite out of a node's AccessLevel (the server
answers BadNotWritable) or UserAccessLevel (BadUserAccessDenied), `retype`
deletes a node and adds it again with another DataType (a controller
re-typed after the client cached the type).

asyncua's server answers BadUserAccessDenied whether AccessLevel or
UserAccessLevel lacks CurrentWrite; the spec's answer for a node that is not
writable at all is BadNotWritable, so this sim's PostWrite hook rewrites that
case to BadNotWritable (what a conforming controller sends).

Security (certificate, policies, user names; `OpcUaSimSecurity`):
`drivers.sim.opcua_security`.

The first start in a process costs about a second (asyncua builds the
standard address space), later ones about 10 ms of CPU and 0.6 MB: each server
shares the standard nodes it never looks up with the others of its process
(`drivers.opcua_space`); stopping is immediate (the server clock task is
disabled).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Mapping, Sequence
from datetime import UTC
from typing import Any

from asyncua import ua
from asyncua.common.callback import CallbackType, ServerItemCallback
from asyncua.server.server import Server
from asyncua.ua.attribute_ids import AttributeIds
from asyncua.ua.status_codes import StatusCodes

from drivers.addresses import Address, OpcUaAddress
from drivers.opcua_codec import INT_RANGES
from drivers.opcua_space import CopiedSpaceInternalServer
from drivers.sim import CHANNELS, OUTPUTS, PROBES
from drivers.sim.opcua_security import POLICY_TYPES, OpcUaSimSecurity, secure, user_manager
from drivers.sim.ports import free_tcp_port, start_on_free_port
from drivers.sim.renamed import FORMER_NAMES, warn_former
from drivers.sim.temp_comp import SINUMERIK_DATA, SINUMERIK_SCALES, TOOL_DATA, line_of
from drivers.temp_comp import AXES, PARAMETERS, AxisCompensation, output_name

__all__ = ["CHANNEL_TYPES", "ENCODING_NODES", "FORMER_NODES", "NAMESPACE", "NAMESPACE_INDEX",
           "OUTPUT_TYPES", "POLICY_TYPES", "TEMP_COMP_NODES", "OpcUaSimController",
           "OpcUaSimSecurity", "node_id"]

NAMESPACE = "urn:compd:sim"
#: asyncua gives the first registered namespace index 2 (0: OPC UA, 1: the server)
NAMESPACE_INDEX = 2

_VT = ua.VariantType
#: name -> variant type of the node on the simulated controller
CHANNEL_TYPES: dict[str, ua.VariantType] = {name: _VT.Double for name in CHANNELS}
CHANNEL_TYPES["power_kw"] = _VT.Float
CHANNEL_TYPES.update({"probe_value": _VT.Double, "probe_counter": _VT.UInt32})
OUTPUT_TYPES: dict[str, ua.VariantType] = {
    "offset": _VT.Float, "heartbeat": _VT.UInt32, "status": _VT.UInt16}
#: a channel's node under its former name -> the channel (module docstring)
FORMER_NODES: dict[str, str] = {old: new for old, new in FORMER_NAMES.items()
                                if new in CHANNEL_TYPES}
#: extra writable nodes for encoding tests: name -> (type, scale)
ENCODING_NODES: dict[str, tuple[ua.VariantType, float]] = {
    "enc_int16": (_VT.Int16, 0.1),
    "enc_int32": (_VT.Int32, 0.001),
    "enc_int64": (_VT.Int64, 1.0),
    "enc_double": (_VT.Double, 1.0),
    "enc_float": (_VT.Float, 1.0),
}

#: per-axis temperature-compensation nodes: name -> (node path, scale to compd's units)
TEMP_COMP_NODES: dict[str, tuple[str, float]] = {
    output_name(axis, p): (f"{axis.upper()}.{SINUMERIK_DATA[p]}", SINUMERIK_SCALES[p])
    for axis in AXES for p in PARAMETERS}
#: the channel's tool temperature compensation (SD42960, mm), along the tool
TOOL_NODES: dict[str, tuple[str, float]] = {
    output_name("tool", "value"): (f"Channel.{TOOL_DATA}", SINUMERIK_SCALES["value"])}

_log = logging.getLogger(__name__)


def _now() -> ua.DateTime:
    return ua.DateTime.now(UTC)


def node_id(name: str) -> str:
    """The NodeId string of a sim variable."""
    nodes = {**TEMP_COMP_NODES, **TOOL_NODES}
    path = nodes[name][0] if name in nodes else name
    return f"ns={NAMESPACE_INDEX};s=Machine.{path}"


def _coerce(value: float, vtype: ua.VariantType) -> Any:
    if vtype in INT_RANGES:
        return round(value)
    if vtype is _VT.Boolean:
        return bool(value)
    return float(value)


class OpcUaSimController:
    """The simulated controller (see module docstring)."""

    protocol = "opcua"

    def __init__(self, host: str = "127.0.0.1", port: int = 0, *,
                 security: OpcUaSimSecurity | None = None,
                 writable_channels: bool = False) -> None:
        self.host = host
        #: channel nodes writable by clients too (a HIL bench's plant writes them)
        self.writable_channels = writable_channels
        #: the port was picked here (not named by the caller): it may be picked again
        self._picked = not port
        self.port = port or free_tcp_port(host)
        self.endpoint = f"opc.tcp://{host}:{self.port}"
        self.security = security
        self.channels: dict[str, Address] = {
            name: OpcUaAddress(node=node_id(name)) for name in CHANNELS}
        self.outputs_map: dict[str, Address] = {
            name: OpcUaAddress(node=node_id(name)) for name in OUTPUTS}
        self.probes: dict[str, Address] = {
            name: OpcUaAddress(node=node_id(name)) for name in PROBES}
        self.encodings: dict[str, OpcUaAddress] = {
            name: OpcUaAddress(node=node_id(name), scale=scale)
            for name, (_, scale) in ENCODING_NODES.items()}
        self.temp_comp: dict[str, OpcUaAddress] = {
            name: OpcUaAddress(node=node_id(name), scale=scale)
            for name, (_, scale) in TEMP_COMP_NODES.items()}
        self.tool_comp: dict[str, OpcUaAddress] = {
            name: OpcUaAddress(node=node_id(name), scale=scale)
            for name, (_, scale) in TOOL_NODES.items()}
        self.types: dict[str, ua.VariantType] = {
            **CHANNEL_TYPES, **OUTPUT_TYPES,
            **{name: vt for name, (vt, _) in ENCODING_NODES.items()},
            **dict.fromkeys((*TEMP_COMP_NODES, *TOOL_NODES), _VT.Double),
            **{old: CHANNEL_TYPES[new] for old, new in FORMER_NODES.items()}}
        #: client Read requests that touched this namespace (server-side count)
        self.read_requests = 0
        self.write_requests = 0
        self._latency_s = 0.0
        self._server: Server | None = None
        self._machine: Any = None
        self._nodeids: dict[str, ua.NodeId] = {
            name: ua.NodeId.from_string(node_id(name)) for name in self.types}
        self._former: dict[ua.NodeId, str] = {self._nodeids[old]: old for old in FORMER_NODES}

    # -- lifecycle ---------------------------------------------------------

    async def start(self) -> None:
        if self._server is not None:
            return
        await start_on_free_port(self._start, self._repick, picked=self._picked)

    def _repick(self) -> None:
        self.port = free_tcp_port(self.host)
        self.endpoint = f"opc.tcp://{self.host}:{self.port}"

    async def _start(self) -> None:
        server = Server(iserver=CopiedSpaceInternalServer(
            user_manager=user_manager(self.security)))
        await server.init()
        server.disable_clock()  # its 1 s loop would make stop() take a second
        server.set_endpoint(self.endpoint)
        server.set_server_name("compd simulated controller")
        await secure(server, self.security)
        idx = await server.register_namespace(NAMESPACE)
        if idx != NAMESPACE_INDEX:
            raise RuntimeError(f"sim namespace got index {idx}, expected {NAMESPACE_INDEX}")
        machine = await server.nodes.objects.add_object(
            ua.NodeId(ua.String("Machine"), ua.Int16(idx)), ua.QualifiedName("Machine", idx))
        self._machine = machine
        for name in self.types:
            await self._add_node(name)
        server.subscribe_server_callback(CallbackType.PreRead, self._on_read)
        server.subscribe_server_callback(CallbackType.PreWrite, self._on_write)
        server.subscribe_server_callback(CallbackType.PostWrite, self._after_write)
        await server.start()
        self._server = server

    async def stop(self) -> None:
        server, self._server = self._server, None
        if server is not None:
            await server.stop()

    async def restart(self) -> None:
        """Drop every connection and listen again on the same port; outputs are
        forgotten (a controller power cycle)."""
        server = self._server
        if server is None or server.bserver is None:
            await self.start()
            return
        # Rebind only the listening socket: BinaryServer.stop/start would also
        # replace its cleanup task, which then belongs to the caller's task.
        bserver = server.bserver
        for transport in list(server.iserver.asyncio_transports):
            transport.close()
        if bserver._server is not None:
            bserver._server.close()
            await bserver._server.wait_closed()
        await self.forget_outputs()
        bserver._server = await asyncio.get_running_loop().create_server(
            bserver._make_protocol, self.host, self.port)

    async def __aenter__(self) -> OpcUaSimController:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()

    # -- plant side ----------------------------------------------------------

    async def publish(self, values: Mapping[str, float]) -> None:
        now = _now()
        for name, value in values.items():
            await self._write(name, value, now)
        for old, new in FORMER_NODES.items():
            if new in values:
                await self._write(old, values[new], now)

    async def publish_status(self, name: str, *, bad: bool = True,
                             uncertain: bool = False) -> None:
        """Set a node's status code (keeping its value): Bad (an open sensor),
        Uncertain, or Good again with ``bad=False``."""
        server = self._require()
        nid = self._nodeid(name)
        current = server.read_attribute_value(nid)
        code = (StatusCodes.BadSensorFailure if bad else
                StatusCodes.UncertainLastUsableValue if uncertain else StatusCodes.Good)
        await server.write_attribute_value(nid, ua.DataValue(
            current.Value, StatusCode=ua.StatusCode(ua.UInt32(code)),
            SourceTimestamp=_now(), ServerTimestamp=_now()))

    async def outputs(self) -> dict[str, float]:
        return {name: await self.value(name) for name in OUTPUTS}

    async def value(self, name: str) -> float:
        """The current value of any sim node (engineering value: raw * scale)."""
        server = self._require()
        dv = server.read_attribute_value(self._nodeid(name))
        raw = dv.Value.Value if dv.Value is not None else None
        return float(raw) * self._scale(name) if raw is not None else float("nan")

    async def compensation(self, axis: str) -> AxisCompensation:
        """The line the controller applies to `axis` now (its setting data)."""
        return line_of({output_name(axis, p): await self.value(output_name(axis, p))
                        for p in PARAMETERS}, axis)

    async def forget_outputs(self) -> None:
        """Outputs, encoding nodes and every axis's compensation back at 0 (a restart)."""
        now = _now()
        for name in (*OUTPUTS, *ENCODING_NODES, *TEMP_COMP_NODES, *TOOL_NODES):
            await self._write(name, 0.0, now)

    async def set_write_access(self, name: str, *, writable: bool = True,
                               user_writable: bool = True) -> None:
        """Set CurrentWrite in the node's AccessLevel (`writable`; without it
        a client Write gets BadNotWritable) and UserAccessLevel (`user_writable`;
        without it BadUserAccessDenied)."""
        server = self._require()
        node = server.get_node(self._nodeid(name))
        for attr, on in ((AttributeIds.AccessLevel, writable),
                         (AttributeIds.UserAccessLevel, user_writable)):
            if on:
                await node.set_attr_bit(attr, ua.AccessLevel.CurrentWrite)
            else:
                await node.unset_attr_bit(attr, ua.AccessLevel.CurrentWrite)

    async def retype(self, name: str, vtype: ua.VariantType) -> None:
        """Delete node `name` and add it again (same NodeId, value 0, writable
        as before) with DataType `vtype`."""
        server = self._require()
        await server.delete_nodes([server.get_node(self._nodeid(name))])
        self.types[name] = vtype
        await self._add_node(name)

    def set_latency(self, delay_s: float) -> None:
        """Delay every client Read and Write by `delay_s` (0 = answer at once)."""
        self._latency_s = delay_s

    # -- internals -----------------------------------------------------------

    def _scale(self, name: str) -> float:
        """Engineering value per raw unit of a sim node."""
        if name in self.encodings:
            return self.encodings[name].scale
        scaled = {**self.temp_comp, **self.tool_comp}
        return scaled[name].scale if name in scaled else 1.0

    def _require(self) -> Server:
        if self._server is None:
            raise RuntimeError("sim server not started")
        return self._server

    async def _add_node(self, name: str) -> None:
        vtype = self.types[name]
        var = await self._machine.add_variable(
            self._nodeids[name], ua.QualifiedName(name, NAMESPACE_INDEX),
            ua.Variant(_coerce(0.0, vtype), vtype))
        if name in FORMER_NODES:
            return
        if name not in CHANNEL_TYPES or self.writable_channels:
            await var.set_writable()

    def _nodeid(self, name: str) -> ua.NodeId:
        try:
            return self._nodeids[name]
        except KeyError:
            raise KeyError(f"no sim node named {name!r}") from None

    async def _write(self, name: str, value: float, when: ua.DateTime) -> None:
        server = self._require()
        vtype = self.types[name]
        variant = ua.Variant(_coerce(value / self._scale(name), vtype), vtype)
        await server.write_attribute_value(self._nodeid(name), ua.DataValue(
            variant, SourceTimestamp=when, ServerTimestamp=when))

    def _ours(self, nodeids: Sequence[ua.NodeId]) -> bool:
        return any(n.NamespaceIndex == NAMESPACE_INDEX for n in nodeids)

    async def _on_read(self, event: ServerItemCallback, _dispatcher: Any) -> None:
        if not event.is_external:
            return
        for r in event.request_params.NodesToRead:
            if r.NodeId in self._former:
                warn_former(self._former[r.NodeId], f"OPC UA node {r.NodeId.to_string()}")
        if self._ours([r.NodeId for r in event.request_params.NodesToRead]):
            self.read_requests += 1
            if self._latency_s > 0:
                await asyncio.sleep(self._latency_s)

    async def _after_write(self, event: ServerItemCallback, _dispatcher: Any) -> None:
        """BadUserAccessDenied for a node whose AccessLevel lacks CurrentWrite
        becomes BadNotWritable (see module docstring): the results list is the
        one the server sends."""
        results = event.response_params
        if not event.is_external or not isinstance(results, list):
            return
        server = self._require()
        denied = StatusCodes.BadUserAccessDenied
        for i, wv in enumerate(event.request_params.NodesToWrite):
            if (i < len(results) and results[i].value == denied
                    and wv.AttributeId == AttributeIds.Value):
                al = server.read_attribute_value(wv.NodeId, AttributeIds.AccessLevel)
                bits = al.Value.Value if al.Value is not None else None
                if isinstance(bits, int) and not ua.ua_binary.test_bit(
                        bits, ua.AccessLevel.CurrentWrite):
                    results[i] = ua.StatusCode(ua.UInt32(StatusCodes.BadNotWritable))

    async def _on_write(self, event: ServerItemCallback, _dispatcher: Any) -> None:
        if not event.is_external:
            return
        self.write_requests += 1
        if self._latency_s > 0:
            await asyncio.sleep(self._latency_s)
