"""Modbus TCP driver (pymodbus 3.16.1 async client).

Reads go out as block reads: the requested names are grouped by (unit,
register kind) and covered by as few contiguous requests as possible
(`drivers.modbus_codec.plan_reads`); writes of back-to-back registers go out
as one write-multiple request. A read's request object (pymodbus's PDU) is
built once with its plan and sent again every cycle through the client's
`execute` (which stamps a fresh transaction id on each send): a fleet reads
the same spans every second, and building them was a good part of a
request's own cost.

pymodbus's own defaults are replaced: no retries (a timed-out write is never
sent again), a timeout of `timeout_s`, no automatic reconnect. The connect is
bounded by pymodbus's timeout; each request then by `timeout_s` from its own
start, kept by the driver's `drivers.modbus_watch.RequestWatch` (one timer per
link instead of pymodbus's timer and futures per request). The link is
ours (`drivers.link.Link`, the lifecycle every driver shares): on a lost link
or a timeout the client is dropped, calls fail fast with `ConnectionLost`
until `Backoff` says a new attempt is due, and the next call then opens a
fresh client; after `close()` calls fail until `connect()`.

Modbus carries no quality or source time: every sample is GOOD, stamped with
`time.time()` when its response arrived. Sentinel values (an open Pt100) are
passed through; the daemon validates.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable, Mapping, Sequence
from functools import partial
from typing import Any

from pymodbus.client import AsyncModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException
from pymodbus.pdu import ModbusPDU
from pymodbus.pdu.register_message import (
    ReadHoldingRegistersRequest,
    ReadInputRegistersRequest,
    WriteMultipleRegistersRequest,
)

from drivers.addresses import Address, ModbusAddress
from drivers.backoff import Backoff
from drivers.base import Quality, Sample
from drivers.endpoint import endpoint_of
from drivers.errors import (
    BadAddress,
    ConnectionLost,
    ControllerTimeout,
    DriverError,
    WriteRejected,
)
from drivers.link import Link, LinkedDriver
from drivers.modbus_codec import Span, decode_at, encode, plan_reads, write_spans
from drivers.modbus_watch import RequestWatch, response_future, untimed
from drivers.plans import PlanCache

DEFAULT_PORT = 502
#: exception codes after which a write cannot succeed by retrying:
#: illegal function, illegal data address, illegal data value
PERMANENT_WRITE_CODES = frozenset({1, 2, 3})
#: exception codes that say "not this register" on a read
BAD_ADDRESS_READ_CODES = frozenset({1, 2})


def parse_endpoint(endpoint: str) -> tuple[str, int]:
    """``modbus://host:port`` or ``host:port`` (port defaults to 502;
    `drivers.endpoint`: the checks every caller shares)."""
    ep = endpoint_of("modbus", endpoint)
    return ep.host, ep.port


def _fail_pending(client: AsyncModbusTcpClient) -> None:
    """On a dropped connection, fail the request in flight at once instead of
    letting it wait out the timeout (pymodbus 3.16.1 only notices at timeout)."""
    future = response_future(client)
    if future is not None and not future.done():
        future.set_exception(ConnectionException("connection closed by the controller"))


def _alive(client: AsyncModbusTcpClient) -> bool:
    return bool(client.connected)


async def _drop(client: AsyncModbusTcpClient, closing: bool) -> None:
    client.close()


#: one read of a plan: its span and the request that reads it (built once)
Read = tuple[Span, ModbusPDU]


def read_request(span: Span) -> ModbusPDU:
    """The request that reads `span` (sent as it is every cycle: `client.execute`
    sets its transaction id on each send, nothing else of it changes)."""
    cls = ReadInputRegistersRequest if span.kind == "input" else ReadHoldingRegistersRequest
    return cls(address=span.start, count=span.count, dev_id=span.unit)


def _reads(spans: Sequence[Span]) -> list[Read]:
    return [(span, read_request(span)) for span in spans]


def _check_addresses(role: str, table: Mapping[str, Address]) -> dict[str, ModbusAddress]:
    out: dict[str, ModbusAddress] = {}
    for name, addr in table.items():
        if not isinstance(addr, ModbusAddress):
            raise BadAddress(f"{role} address is not a Modbus address: {addr!r}",
                             channel=name)
        out[name] = addr
    return out


class ModbusDriver(LinkedDriver):
    """Async Modbus TCP access to one controller (see module docstring)."""

    protocol = "modbus"

    def __init__(self, endpoint: str, channels: Mapping[str, Address],
                 outputs: Mapping[str, Address], *, timeout_s: float = 0.5,
                 backoff: Backoff | None = None, max_gap: int = 8) -> None:
        if not timeout_s > 0:
            raise ValueError("timeout_s must be positive")
        self.endpoint = endpoint
        self.host, self.port = parse_endpoint(endpoint)
        self.channels = _check_addresses("channel", channels)
        self.outputs = _check_addresses("output", outputs)
        for name, addr in self.outputs.items():
            if addr.kind != "holding":
                raise BadAddress("outputs must be holding registers (input registers "
                                 "are read-only)", channel=name, address=addr.describe())
        self.timeout_s = timeout_s
        self.max_gap = max_gap
        self._link: Link[AsyncModbusTcpClient] = Link(
            f"{self.host}:{self.port}", backoff if backoff is not None else Backoff(),
            timeout_s, open=self._open, drop=_drop,
            connect_errors=(OSError, ModbusException), alive=_alive)
        self._lock = asyncio.Lock()
        self._plans = PlanCache(self._build_read_plan)
        self._write_plan = PlanCache(
            lambda names: write_spans([(n, self.outputs[n]) for n in names]))
        self._in_flight = False
        self._watch = RequestWatch(timeout_s)

    # -- link -------------------------------------------------------------

    async def connect(self) -> None:
        async with self._lock:
            await self._link.connect()

    async def _open(self) -> AsyncModbusTcpClient:
        client = AsyncModbusTcpClient(
            self.host, port=self.port, name=f"compd-modbus-{self.host}:{self.port}",
            timeout=self.timeout_s, retries=0, reconnect_delay=0, reconnect_delay_max=0,
            trace_connect=lambda up: None if up or not self._in_flight else _fail_pending(client))
        try:
            ok = await client.connect()
        except BaseException:
            client.close()
            raise
        if not ok:
            client.close()
            raise ConnectionRefusedError("connect refused or timed out")
        untimed(client)  # each request's deadline is self._watch's from now on
        return client

    # -- read ---------------------------------------------------------------

    def _lookup(self, name: str) -> ModbusAddress:
        if name in self.channels:
            return self.channels[name]
        if name in self.outputs:
            return self.outputs[name]
        raise BadAddress("unknown channel or output name", channel=name)

    def _build_read_plan(self, names: tuple[str, ...]) -> list[Read]:
        """The reads for this set of names (kept by `_plans`)."""
        items = [(name, self._lookup(name)) for name in dict.fromkeys(names)]
        return _reads(plan_reads(items, max_gap=self.max_gap))

    async def read(self, names: Sequence[str]) -> dict[str, Sample]:
        plan = self._plans(names)
        out: dict[str, Sample] = {}
        async with self._lock:
            for one in plan:
                await self._read_span(names, one, out)
        return out

    async def _read_span(self, names: Sequence[str], one: Read,
                         out: dict[str, Sample]) -> None:
        span, request = one
        response = await self._call(request, span)
        if response.isError():
            code = int(getattr(response, "exception_code", 0))
            if code in BAD_ADDRESS_READ_CODES and len(span.items) > 1:
                # The merged span crossed a register the controller refuses:
                # read item by item from now on, which also names the culprit.
                spans = plan_reads([span.items[0]], max_gap=0)
                for item in span.items[1:]:
                    spans += plan_reads([item], max_gap=0)
                singles = _reads(spans)
                plan = self._plans(names)
                if one in plan:
                    idx = plan.index(one)
                    self._plans.put(names, plan[:idx] + singles + plan[idx + 1:])
                for single in singles:
                    await self._read_span(names, single, out)
                return
            name, addr = span.items[0]
            if code in BAD_ADDRESS_READ_CODES:
                raise BadAddress(f"controller refused the read (exception code {code})",
                                 channel=name, address=addr.describe())
            raise DriverError(f"controller answered the read with exception code {code}",
                              channel=span.names, address=span.describe())
        now_s = time.time()
        registers: list[int] = response.registers
        if len(registers) < span.count:
            raise DriverError(f"short response: {len(registers)} of {span.count} registers",
                              channel=span.names, address=span.describe())
        start = span.start
        for name, addr in span.items:
            out[name] = Sample(decode_at(addr, registers, addr.address - start), now_s,
                               Quality.GOOD)

    def _call(self, request: ModbusPDU, span: Span) -> Awaitable[Any]:
        """One pymodbus request on the link (`drivers.link.Link` rules)."""
        return self._link.call(partial(self._exchange, request, span), "request",
                               where=span.where)

    async def _exchange(self, request: ModbusPDU, span: Span,
                        client: AsyncModbusTcpClient) -> Any:
        """Await one pymodbus request, turning its failures into ours."""
        self._in_flight = True
        self._watch.begin(client)
        try:
            return await client.execute(False, request)
        except ConnectionException as exc:
            raise ConnectionLost(f"link lost: {exc}", channel=span.names,
                                 address=span.describe()) from exc
        except ModbusIOException as exc:
            # No answer within timeout_s (retries=0). The link drops the
            # client: a late answer must not be taken for the next request's.
            raise ControllerTimeout(f"no answer within {self.timeout_s} s: {exc}",
                                    channel=span.names, address=span.describe()) from exc
        except (ModbusException, OSError) as exc:
            raise ConnectionLost(f"request failed: {exc}", channel=span.names,
                                 address=span.describe()) from exc
        finally:
            self._in_flight = False
            self._watch.end()

    async def close(self) -> None:
        self._watch.close()
        await super().close()

    # -- write --------------------------------------------------------------

    async def write(self, values: Mapping[str, float]) -> None:
        encoded: dict[str, list[int]] = {}
        for name, value in values.items():
            addr = self.outputs.get(name)
            if addr is None:
                raise BadAddress("unknown output name (not writable)", channel=name)
            encoded[name] = encode(addr, float(value), channel=name)
        requests = [(span, [w for n, _ in span.items for w in encoded[n]])
                    for span in self._write_plan(tuple(values))]
        async with self._lock:
            for span, words in requests:
                await self._write_span(span, words)

    async def _write_span(self, span: Span, words: list[int]) -> None:
        response = await self._call(
            WriteMultipleRegistersRequest(address=span.start, registers=words, dev_id=span.unit),
            span)
        if response.isError():
            code = int(getattr(response, "exception_code", 0))
            name, addr = span.items[0]
            channel = span.names
            address = addr.describe() if len(span.items) == 1 else span.describe()
            raise WriteRejected(f"controller refused the write (exception code {code})",
                                channel=channel if len(span.items) > 1 else name,
                                address=address, permanent=code in PERMANENT_WRITE_CODES)
