"""OPC UA driver (asyncua client).

One Read service call per `read()` (every requested node in one ReadRequest,
parameters prebuilt per name set), one Write call per `write()` with each
output's own VariantType (read once from the node's DataType after connect:
a Python float sent to a Float node is a BadTypeMismatch otherwise). A
BadTypeMismatch later re-reads that DataType once: when the controller has
re-typed the node since, the write is a transient refusal (the next one uses
the new type); when the type is the same, a permanent one.

Every call runs under `drivers.deadline.deadline(timeout_s)` and the client's own
request timeout is the same; a connect's handshake is bounded by `connect_timeout_s`
as a whole (its requests too). asyncua's `auto_reconnect` is NOT used (it
blocks calls for seconds): on a connection-level failure the client is torn
down (its supervisor, watchdog and renew tasks cancelled) and the next call
builds a new client when the backoff allows, else fails fast with
`ConnectionLost` (`drivers.link.Link`, the lifecycle every driver shares).
"""

from __future__ import annotations

import logging
from collections.abc import Awaitable, Callable, Mapping, Sequence
from functools import partial
from typing import TypeVar

from asyncua import ua
from asyncua.client.client import Client
from asyncua.ua.attribute_ids import AttributeIds
from asyncua.ua.status_codes import StatusCodes
from asyncua.ua.uaerrors import UaError, UaStatusCodeError

from drivers.addresses import OpcUaAddress
from drivers.backoff import Backoff
from drivers.base import Sample
from drivers.deadline import deadline
from drivers.endpoint import endpoint_of
from drivers.errors import BadAddress, ConnectionLost, ControllerTimeout, DriverError, WriteRejected
from drivers.link import Link, LinkedDriver
from drivers.opcua_codec import (
    ADDRESS_CODES,
    PERMANENT_WRITE_CODES,
    SESSION_CODES,
    decode,
    encode,
    status_name,
    variant_type_of,
)
from drivers.opcua_security import OpcUaSecurity, SecurityRejected, apply_security

__all__ = ["OpcUaDriver", "OpcUaSecurity", "SecurityRejected"]

_log = logging.getLogger(__name__)
_T = TypeVar("_T")
_SC = StatusCodes
#: the requested session lifetime: a dropped client's session ends soon on the server
_SESSION_TIMEOUT_MS = 60_000
#: asyncua's own liveness probe period (our calls detect failures themselves)
_WATCHDOG_S = 5.0
#: a service fault on a write that retrying cannot cure
_PERMANENT_SERVICE_CODES = PERMANENT_WRITE_CODES | {_SC.BadNothingToDo}
_CONNECTION_ERRORS = (OSError, ConnectionError, UaError, EOFError)



class OpcUaDriver(LinkedDriver):
    """Async access to one OPC UA server (see module docstring)."""

    protocol = "opcua"

    def __init__(self, endpoint: str, channels: dict[str, OpcUaAddress],
                 outputs: dict[str, OpcUaAddress], *, timeout_s: float = 0.5,
                 backoff: Backoff | None = None, security: OpcUaSecurity | None = None,
                 connect_timeout_s: float | None = None) -> None:
        endpoint_of("opcua", endpoint)  # the checks every caller shares (drivers.endpoint)
        if timeout_s <= 0:
            raise ValueError("timeout_s must be > 0")
        self.endpoint = endpoint
        self.timeout_s = timeout_s
        #: a secured connect costs a discovery round trip and RSA operations
        self.connect_timeout_s = connect_timeout_s or max(2 * timeout_s, 1.0)
        self.security = security or OpcUaSecurity()
        self._addresses: dict[str, OpcUaAddress] = {}
        for name, addr in (*channels.items(), *outputs.items()):
            if not isinstance(addr, OpcUaAddress):
                raise TypeError(f"{name}: expected OpcUaAddress, got {type(addr).__name__}")
            if self._addresses.get(name, addr) != addr:
                raise ValueError(f"{name!r} is both a channel and an output, at different nodes")
            self._addresses[name] = addr
        self._outputs = dict(outputs)
        self._nodeids = {name: ua.NodeId.from_string(addr.node)
                         for name, addr in self._addresses.items()}
        self._read_params: dict[tuple[str, ...], ua.ReadParameters] = {}
        #: output name -> VariantType, or the status name why it cannot be written
        self._types: dict[str, ua.VariantType | str] = {}
        self._link: Link[Client] = Link(
            endpoint, backoff or Backoff(), timeout_s, open=self._open, drop=self._dispose,
            connect_errors=(*_CONNECTION_ERRORS, ValueError),
            connect_timeout_s=self.connect_timeout_s)

    # -- link ------------------------------------------------------------------

    async def _open(self) -> Client:
        """A connected client with the output types loaded (`Link` wraps the
        failures it does not name itself)."""
        # the handshake's requests (discovery, hello, secure channel, session,
        # activation: RSA work on both sides under security; the outputs' types)
        # are bounded by the connect's deadline as a whole: with the request
        # timeout on each, a server slower than a cycle's read at one of them
        # could never be connected to
        client = Client(self.endpoint, timeout=self.connect_timeout_s,
                        watchdog_intervall=_WATCHDOG_S)
        client.session_timeout = _SESSION_TIMEOUT_MS
        client.name = client.description = "compd"
        try:
            async with deadline(self.connect_timeout_s):
                await apply_security(client, self.security)
                await client.connect()
                await self._load_output_types(client)
            self._request_timeout(client)
        except UaStatusCodeError as exc:
            await self._dispose(client, False)
            raise self._refused(exc) from None
        except BaseException:
            # cancelled too, e.g. by the caller's own deadline: a failed attempt
            await self._dispose(client, False)
            raise
        return client

    def _request_timeout(self, client: Client) -> None:
        """From now on the client's own request timeout is `timeout_s` (its socket
        protocol's, which every later request of this client takes)."""
        protocol = client.uaclient.protocol
        if protocol is not None:
            protocol.timeout = self.timeout_s

    def _refused(self, exc: UaStatusCodeError) -> DriverError:
        code = exc.code
        name = status_name(code)
        if code in {_SC.BadUserAccessDenied, _SC.BadIdentityTokenInvalid,
                    _SC.BadIdentityTokenRejected, _SC.BadCertificateUntrusted,
                    _SC.BadCertificateInvalid, _SC.BadSecurityChecksFailed,
                    _SC.BadSecurityPolicyRejected, _SC.BadCertificateUriInvalid,
                    _SC.BadCertificateTimeInvalid, _SC.BadCertificateUseNotAllowed}:
            who = f" as user {self.security.username!r}" if self.security.username else ""
            return SecurityRejected(f"the server refused the session{who}: {name}",
                                    address=self.endpoint)
        return ConnectionLost(f"cannot connect: {name}", address=self.endpoint)

    async def _load_output_types(self, client: Client) -> None:
        names = list(self._outputs)
        if not names:
            return
        results = await client.uaclient.read_attributes(
            [self._nodeids[n] for n in names], AttributeIds.DataType)
        for name, dv in zip(names, results, strict=True):
            status = dv.StatusCode
            if status is not None and not status.is_good():
                self._types[name] = status_name(status.value)
                continue
            vtype = variant_type_of(dv.Value.Value) if dv.Value is not None else None
            self._types[name] = vtype if vtype is not None else \
                f"DataType {dv.Value.Value if dv.Value is not None else None} not numeric"

    async def _dispose(self, client: Client, graceful: bool) -> None:
        """Tear a client down quietly: its background tasks are cancelled first
        (inside close_session), then the session/channel are closed if the link
        still works, then the socket. Without `graceful` the socket goes first:
        nothing waits on a hung server."""
        if not graceful:
            client.disconnect_socket()
        try:
            async with deadline(self.timeout_s):
                await client.close_session()
        except Exception:  # a dead link: CloseSession cannot be sent
            _log.debug("close_session failed during teardown", exc_info=True)
        if graceful:
            try:
                async with deadline(self.timeout_s):
                    await client.close_secure_channel()
            except Exception:
                _log.debug("close_secure_channel failed during teardown", exc_info=True)
        client.disconnect_socket()

    # -- read ----------------------------------------------------------------

    def _params_for(self, names: tuple[str, ...]) -> ua.ReadParameters:
        params = self._read_params.get(names)
        if params is not None:
            return params
        for name in names:
            if name not in self._addresses:
                raise BadAddress("not a configured channel or output", channel=name)
        params = ua.ReadParameters()
        params.TimestampsToReturn = ua.TimestampsToReturn.Both
        params.MaxAge = 0
        for name in names:
            rv = ua.ReadValueId()
            rv.NodeId = self._nodeids[name]
            rv.AttributeId = AttributeIds.Value
            params.NodesToRead.append(rv)
        self._read_params[names] = params
        return params

    async def read(self, names: Sequence[str]) -> dict[str, Sample]:
        key = tuple(names)
        params = self._params_for(key)
        if not key:
            return {}
        where = key
        try:
            results = await self._link.call(partial(self._read, params, where), "Read",
                                            where, self.endpoint)
        except UaStatusCodeError as exc:
            raise self._fault(exc, where) from None
        if len(results) != len(key):
            raise DriverError(f"Read returned {len(results)} results for {len(key)} nodes",
                              channel=where, address=self.endpoint)
        return {name: decode(dv, self._addresses[name], name)
                for name, dv in zip(key, results, strict=True)}

    async def _read(self, params: ua.ReadParameters, where: tuple[str, ...],
                    client: Client) -> list[ua.DataValue]:
        return await self._service("Read", partial(client.uaclient.read, params), where)

    async def _service(self, service: str, request: Callable[[], Awaitable[_T]],
                       where: tuple[str, ...], timeout_note: str = "") -> _T:
        """One request within timeout_s: no answer is a ControllerTimeout (with
        `timeout_note`, e.g. that a Write may have been applied), a lost socket a
        ConnectionLost, a status that ends the session too; another refused status is
        raised as it is, for the caller to judge."""
        try:
            async with deadline(self.timeout_s):
                return await request()
        except TimeoutError:
            raise ControllerTimeout(f"{service} did not answer within {self.timeout_s} s"
                                    f"{timeout_note}", channel=where,
                                    address=self.endpoint) from None
        except UaStatusCodeError as exc:
            self._session_fault(exc, where)
            raise
        except _CONNECTION_ERRORS as exc:
            raise ConnectionLost(f"{service} failed: {type(exc).__name__}: {exc}",
                                 channel=where, address=self.endpoint) from None

    def _session_fault(self, exc: UaStatusCodeError, where: tuple[str, ...]) -> None:
        """A fault that ends the session is a lost link (raised)."""
        if exc.code in SESSION_CODES:
            raise ConnectionLost(f"session lost: {status_name(exc.code)}", channel=where,
                                 address=self.endpoint) from None

    def _fault(self, exc: UaStatusCodeError, where: tuple[str, ...]) -> DriverError:
        """A whole-request fault the server answered (the link stays up)."""
        name = status_name(exc.code)
        if exc.code == _SC.BadTimeout:
            return ControllerTimeout(f"server answered {name}", channel=where,
                                     address=self.endpoint)
        return DriverError(f"server refused the request: {name}", channel=where,
                           address=self.endpoint)

    # -- write ---------------------------------------------------------------

    async def write(self, values: Mapping[str, float]) -> None:
        if not values:
            return
        for name in values:
            if name not in self._outputs:
                raise BadAddress("not a configured output", channel=name)
        where = tuple(values)
        try:
            await self._link.call(partial(self._write, values, where), "Write", where,
                                  self.endpoint)
        except UaStatusCodeError as exc:
            if exc.code == _SC.BadTimeout:
                raise self._fault(exc, where) from None
            raise WriteRejected(f"server refused the Write: {status_name(exc.code)}",
                                channel=where, address=self.endpoint,
                                permanent=exc.code in _PERMANENT_SERVICE_CODES) from None

    def _write_params(self, values: Mapping[str, float]) -> ua.WriteParameters:
        """The WriteRequest, each value in its node's type (known once connected)."""
        params = ua.WriteParameters()
        for name, value in values.items():
            addr = self._outputs[name]
            vtype = self._types.get(name)
            if not isinstance(vtype, ua.VariantType):
                raise BadAddress(f"cannot write this node: {vtype or 'type unknown'}",
                                 channel=name, address=addr.node)
            wv = ua.WriteValue()
            wv.NodeId = self._nodeids[name]
            wv.AttributeId = AttributeIds.Value
            wv.Value = ua.DataValue(encode(value, addr, vtype, name))
            params.NodesToWrite.append(wv)
        return params

    async def _write(self, values: Mapping[str, float], where: tuple[str, ...],
                     client: Client) -> None:
        params = self._write_params(values)
        results = await self._service("Write", partial(client.uaclient.write, params), where,
                                      " (it may have been applied)")
        for name, status in zip(values, results, strict=True):
            if status.is_good():
                continue
            code = status.value
            node = self._outputs[name].node
            if code in ADDRESS_CODES:
                raise BadAddress(f"the server answered {status_name(code)}",
                                 channel=name, address=node)
            if code == _SC.BadTypeMismatch:
                retyped = await self._reread_type(client, name)
                if retyped is not None:
                    raise WriteRejected(
                        f"the server refused the value: BadTypeMismatch ({retyped}): "
                        "retried next cycle", channel=name, address=node, permanent=False)
            raise WriteRejected(f"the server refused the value: {status_name(code)}",
                                channel=name, address=node,
                                permanent=code in PERMANENT_WRITE_CODES)

    async def _reread_type(self, client: Client, name: str) -> str | None:
        """After a BadTypeMismatch: read the output node's DataType again (a
        controller may re-type a node after our type cache was built). Returns
        why the write is worth retrying (the type changed, or could not be
        read just now), None when the cached type stands (then the mismatch is
        ours: permanent)."""
        before = self._types.get(name)
        try:
            async with deadline(self.timeout_s):
                dv = (await client.uaclient.read_attributes(
                    [self._nodeids[name]], AttributeIds.DataType))[0]
        except (TimeoutError, UaStatusCodeError, *_CONNECTION_ERRORS) as exc:
            return f"DataType not re-read: {type(exc).__name__}"
        if dv.StatusCode is not None and not dv.StatusCode.is_good():
            return f"DataType not re-read: {status_name(dv.StatusCode.value)}"
        vtype = variant_type_of(dv.Value.Value) if dv.Value is not None else None
        if vtype is None or vtype == before:
            return None
        self._types[name] = vtype
        old = before.name if isinstance(before, ua.VariantType) else before
        return f"the node's type changed from {old} to {vtype.name}"
