"""Modbus TCP driver (its own client, `drivers.modbus_tcp`).

Reads go out as block reads: the requested names are grouped by (unit,
register kind) and covered by as few contiguous requests as possible
(`drivers.modbus_codec.plan_reads`); writes of back-to-back registers go out
as one write-multiple request.

A request is sent once (a timed-out write is never sent again) and waits at
most `timeout_s` for its answer; nothing reconnects by itself. The link is
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
from collections.abc import Awaitable, Callable, Mapping, Sequence
from functools import partial

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
from drivers.modbus_tcp import READ_HOLDING, READ_INPUT, ModbusTcpClient, Reply
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


def _alive(client: ModbusTcpClient) -> bool:
    return client.connected


async def _drop(client: ModbusTcpClient, closing: bool) -> None:
    client.close()


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
        self._link: Link[ModbusTcpClient] = Link(
            f"{self.host}:{self.port}", backoff if backoff is not None else Backoff(),
            timeout_s, open=self._open, drop=_drop, connect_errors=(OSError,), alive=_alive)
        self._lock = asyncio.Lock()
        self._plans = PlanCache(self._build_read_plan)
        self._write_plan = PlanCache(
            lambda names: write_spans([(n, self.outputs[n]) for n in names]))

    # -- link -------------------------------------------------------------

    async def connect(self) -> None:
        async with self._lock:
            await self._link.connect()

    async def _open(self) -> ModbusTcpClient:
        return await ModbusTcpClient.open(self.host, self.port, self.timeout_s)

    # -- read ---------------------------------------------------------------

    def _lookup(self, name: str) -> ModbusAddress:
        if name in self.channels:
            return self.channels[name]
        if name in self.outputs:
            return self.outputs[name]
        raise BadAddress("unknown channel or output name", channel=name)

    def _build_read_plan(self, names: tuple[str, ...]) -> list[Span]:
        """The spans for this set of names (kept by `_plans`)."""
        items = [(name, self._lookup(name)) for name in dict.fromkeys(names)]
        return plan_reads(items, max_gap=self.max_gap)

    async def read(self, names: Sequence[str]) -> dict[str, Sample]:
        plan = self._plans(names)
        out: dict[str, Sample] = {}
        async with self._lock:
            for span in plan:
                await self._read_span(names, span, out)
        return out

    async def _read_span(self, names: Sequence[str], span: Span,
                         out: dict[str, Sample]) -> None:
        function = READ_INPUT if span.kind == "input" else READ_HOLDING
        response = await self._call(
            partial(_read_request, span.unit, function, span.start, span.count), span)
        code = response.exception_code
        if code:
            if code in BAD_ADDRESS_READ_CODES and len(span.items) > 1:
                # The merged span crossed a register the controller refuses:
                # read item by item from now on, which also names the culprit.
                singles = plan_reads([span.items[0]], max_gap=0)
                for item in span.items[1:]:
                    singles += plan_reads([item], max_gap=0)
                plan = self._plans(names)
                if span in plan:
                    idx = plan.index(span)
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
        registers = response.registers
        if len(registers) < span.count:
            raise DriverError(f"short response: {len(registers)} of {span.count} registers",
                              channel=span.names, address=span.describe())
        start = span.start
        for name, addr in span.items:
            out[name] = Sample(decode_at(addr, registers, addr.address - start), now_s,
                               Quality.GOOD)

    def _call(self, request: Callable[[ModbusTcpClient], Awaitable[Reply]],
              span: Span) -> Awaitable[Reply]:
        """One request on the link (`drivers.link.Link` rules)."""
        return self._link.call(partial(self._exchange, request, span), "request",
                               where=span.where)

    async def _exchange(self, request: Callable[[ModbusTcpClient], Awaitable[Reply]],
                        span: Span, client: ModbusTcpClient) -> Reply:
        """Await one request, turning its failures into ours."""
        try:
            return await request(client)
        except TimeoutError as exc:
            # No answer within timeout_s: the link drops the client (a late answer
            # must not be taken for the next request's; the client closed it too).
            raise ControllerTimeout(f"no answer within {self.timeout_s} s: {exc}",
                                    channel=span.names, address=span.describe()) from exc
        except ConnectionError as exc:
            raise ConnectionLost(f"link lost: {exc}", channel=span.names,
                                 address=span.describe()) from exc
        except OSError as exc:
            raise ConnectionLost(f"request failed: {exc}", channel=span.names,
                                 address=span.describe()) from exc

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
        response = await self._call(partial(_write_request, span.unit, span.start, words), span)
        code = response.exception_code
        if code:
            name, addr = span.items[0]
            channel = span.names
            address = addr.describe() if len(span.items) == 1 else span.describe()
            raise WriteRejected(f"controller refused the write (exception code {code})",
                                channel=channel if len(span.items) > 1 else name,
                                address=address, permanent=code in PERMANENT_WRITE_CODES)


def _read_request(unit: int, function: int, start: int, count: int,
                  client: ModbusTcpClient) -> Awaitable[Reply]:
    return client.read_registers(unit, function, start, count)


def _write_request(unit: int, start: int, words: list[int],
                   client: ModbusTcpClient) -> Awaitable[Reply]:
    return client.write_registers(unit, start, words)
