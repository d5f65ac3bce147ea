"""Siemens S7 driver over python-snap7 3.3.0 (pure Python, blocking).

Every snap7 call runs on one dedicated worker thread (`IoThread`). A read
makes one `db_read` per DB covering all requested values of that DB; a write
makes one `db_write` per run of byte-adjacent outputs (snap7 3.3.0's
`write_multi_vars` is only a loop of single writes, so it saves nothing).

Two snap7 defaults are overridden (docs/protocols.md §9):
- `RecvTimeout` is stored but never applied; the ISO connection's socket
  keeps a 5 s timeout. Before each request the driver sets the connected
  socket's own timeout (``client.connection.socket``) to what is left of the
  call's deadline.
- `Client.connect` always waits up to 5 s for the COTP handshake. The driver
  connects the way `Client._connect` does but passes its own timeout to
  `ISOTCPConnection.connect` (this uses snap7 internals; the version is
  pinned exactly for that reason).

After any link failure the client is disconnected; the next call after the
backoff delay connects a fresh ISO connection (a restarted PLC leaves the
old client "not connected" forever otherwise). Calls on a down link inside
the backoff delay fail fast with `ConnectionLost` (`drivers.link.WorkerLink`:
the lifecycle every driver shares).
"""

from __future__ import annotations

import contextlib
import re
import time
from collections.abc import Awaitable, Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TypeVar

from snap7.client import Client
from snap7.connection import ISOTCPConnection
from snap7.error import S7ConnectionError, S7Error, S7ProtocolError, S7TimeoutError

from drivers.addresses import S7Address
from drivers.backoff import Backoff
from drivers.base import Quality, Sample, select_addresses
from drivers.endpoint import endpoint_of
from drivers.errors import BadAddress, DriverError, WriteRejected
from drivers.io_thread import IoThread
from drivers.link import LinkedDriver, WorkerLink
from drivers.plans import PlanCache
from drivers.s7_codec import Span, decode, encode, read_spans, write_runs

T = TypeVar("T")

#: S7 item return codes that mean "this address does not exist here"
_ADDRESS_CODES = {0x05, 0x06, 0x07, 0x0A}
#: S7 header error codes the snap7 server (and some CPUs) use for the same
_ADDRESS_HEADER_CODES = {0x8001, 0x8404}
_ITEM_CODE_RE = re.compile(r"\(0x([0-9a-fA-F]{2})\)")


def parse_endpoint(endpoint: str) -> tuple[str, int]:
    """``s7://host[:port]`` -> (host, port); port 102 by default
    (`drivers.endpoint`: the checks every caller shares)."""
    ep = endpoint_of("s7", endpoint)
    return ep.host, ep.port


def _s7_code(exc: S7Error) -> int | None:
    """The header error word snap7 attaches, else the item return code in its message."""
    if exc.error_code:
        return int(exc.error_code)
    m = _ITEM_CODE_RE.search(str(exc))
    return int(m.group(1), 16) if m else None


class _Deadline:
    """The time left for one worker-thread call."""

    def __init__(self, timeout_s: float) -> None:
        self.end_s = time.monotonic() + timeout_s

    def left_s(self) -> float:
        left = self.end_s - time.monotonic()
        if left <= 0:
            raise TimeoutError("call deadline passed")
        return left


@dataclass(frozen=True, slots=True)
class _ReadPlan:
    """How to read one set of names: the spans, and per span who sits where."""

    wanted: dict[str, S7Address]
    spans: tuple[Span, ...]
    fields: tuple[tuple[tuple[str, S7Address, int], ...], ...]
    channel: str | None  # named in errors when the read is of one channel


class S7Driver(LinkedDriver):
    """Async driver for one S7 CPU (DB areas only)."""

    protocol = "s7"

    def __init__(self, endpoint: str, channels: Mapping[str, S7Address],
                 outputs: Mapping[str, S7Address], *, timeout_s: float = 0.5,
                 backoff: Backoff | None = None, rack: int = 0, slot: int = 1) -> None:
        if timeout_s <= 0:
            raise ValueError("timeout_s must be positive")
        self.endpoint = endpoint
        self._host, self._port = parse_endpoint(endpoint)
        for name, addr in {**channels, **outputs}.items():
            if not isinstance(addr, S7Address):
                raise TypeError(f"{name}: {type(addr).__name__} is not an S7Address")
        self._channels = dict(channels)
        self._outputs = dict(outputs)
        self._all = {**self._channels, **self._outputs}
        self._timeout_s = timeout_s
        self._rack = rack
        self._slot = slot
        self._client: Client | None = None  # touched only on the worker thread
        self._link: WorkerLink[Client] = WorkerLink(
            endpoint, backoff or Backoff(), timeout_s, io=IoThread("s7-io"),
            open_sync=lambda: self._connect_sync(_Deadline(self._timeout_s)),
            drop_sync=self._drop_sync, drop_on=(S7ConnectionError, S7TimeoutError, OSError),
            connect_errors=(S7Error, OSError), timeout_errors=(S7TimeoutError,),
            lost_errors=(S7ConnectionError, OSError))
        self._read_plan = PlanCache(self._build_read_plan)
        self._write_plan = PlanCache(self._build_write_plan)

    @property
    def io_thread(self) -> IoThread:
        return self._link.io

    # ---- worker-thread side -------------------------------------------------

    def _drop_sync(self) -> None:
        client, self._client = self._client, None
        if client is not None:
            with contextlib.suppress(S7Error, OSError):
                client.disconnect()

    def _connect_sync(self, deadline: _Deadline) -> Client:
        """Connect as `Client._connect` does, with our own handshake timeout."""
        self._drop_sync()
        client = Client()
        client.remote_tsap = (client.connection_type << 8) | (self._rack << 5) | self._slot
        client.host, client.port = self._host, self._port
        client.rack, client.slot = self._rack, self._slot
        conn = ISOTCPConnection(host=self._host, port=self._port,
                                local_tsap=client.local_tsap, remote_tsap=client.remote_tsap)
        client.connection = conn
        try:
            conn.connect(timeout=deadline.left_s())
            self._arm(client, deadline)
            client._setup_communication()
        except BaseException:
            client.disconnect()
            raise
        client.connected = True
        self._client = client
        return client

    @staticmethod
    def _arm(client: Client, deadline: _Deadline) -> None:
        """Apply the call's remaining time to the connected socket."""
        conn = client.connection
        if conn is None or conn.socket is None:
            raise S7ConnectionError("not connected")
        left = deadline.left_s()
        conn.timeout = left
        conn.socket.settimeout(left)

    # ---- event-loop side ----------------------------------------------------

    def _call(self, op: Callable[[Client, _Deadline], T], what: str,
              channel: str | None = None, address: str | None = None) -> Awaitable[T]:
        """`op(client, deadline)` on the worker thread (`WorkerLink` rules)."""
        timeout_s = self._timeout_s
        return self._link.run(lambda client: op(client, _Deadline(timeout_s)),
                              what, channel, address)

    def _build_read_plan(self, names: tuple[str, ...]) -> _ReadPlan:
        """The spans for this set of names (kept by `_read_plan`)."""
        wanted = select_addresses(names, self._all, "channel")
        spans = tuple(read_spans(wanted))
        fields = tuple(tuple((n, wanted[n], wanted[n].offset - sp.start) for n in sp.names)
                       for sp in spans)
        return _ReadPlan(wanted, spans, fields, names[0] if len(wanted) == 1 else None)

    async def read(self, names: Sequence[str]) -> dict[str, Sample]:
        plan = self._read_plan(names)
        if not plan.spans:
            return {}
        spans = plan.spans
        arm = self._arm

        def op(client: Client, deadline: _Deadline) -> list[bytes | S7Error]:
            results: list[bytes | S7Error] = []
            for span in spans:  # every DB of the read in this one worker job
                arm(client, deadline)
                try:
                    results.append(bytes(client.db_read(span.db, span.start, span.size)))
                except S7ProtocolError as exc:
                    results.append(exc)
            return results

        results = await self._call(op, "read", channel=plan.channel)
        now = time.time()
        samples: dict[str, Sample] = {}
        for span, fields, data in zip(spans, plan.fields, results, strict=True):
            if isinstance(data, S7Error):
                await self._blame(span, plan.wanted, data)
                continue
            for name, addr, at in fields:
                samples[name] = Sample(decode(addr, data, at), now, Quality.GOOD)
        return {name: samples[name] for name in names}

    async def _blame(self, span: Span, wanted: Mapping[str, S7Address], exc: S7Error) -> None:
        """A span read was refused: find the channel whose address is bad."""
        for name in span.names:
            addr = wanted[name]

            def probe(client: Client, deadline: _Deadline, a: S7Address = addr) -> S7Error | None:
                self._arm(client, deadline)
                try:
                    client.db_read(a.db, a.offset, a.size)
                except S7ProtocolError as refused:
                    return refused
                return None

            err = await self._call(probe, "read", channel=name, address=addr.describe())
            if err is not None:
                raise BadAddress(f"controller refused the read: {err}", channel=name,
                                 address=addr.describe()) from err
        name = span.names[0]
        raise BadAddress(f"controller refused the read of DB{span.db}.{span.start}+{span.size}: "
                         f"{exc}", channel=name, address=wanted[name].describe()) from exc

    def _build_write_plan(self, names: tuple[str, ...]) -> tuple[dict[str, S7Address],
                                                                  list[Span]]:
        """The runs for this set of outputs (kept by `_write_plan`)."""
        wanted = select_addresses(names, self._outputs, "output")
        return wanted, write_runs(wanted.items())

    async def write(self, values: Mapping[str, float]) -> None:
        wanted, runs = self._write_plan(tuple(values))
        payload: dict[str, bytes] = {}
        for name, addr in wanted.items():
            try:
                payload[name] = encode(addr, float(values[name]))
            except (ValueError, TypeError, OverflowError) as exc:
                raise BadAddress(f"cannot encode {values[name]!r}: {exc}", channel=name,
                                 address=addr.describe()) from exc
        datas = [bytearray(b"".join([payload[n] for n in run.names])) for run in runs]
        arm = self._arm

        def op(client: Client, deadline: _Deadline) -> tuple[Span, S7Error] | None:
            for run, data in zip(runs, datas, strict=True):  # all runs in this one job
                arm(client, deadline)
                try:
                    client.db_write(run.db, run.start, data)
                except S7ProtocolError as exc:
                    return run, exc
            return None

        failed = await self._call(op, "write")
        if failed is not None:
            run, refused = failed
            name = run.names[0]
            raise _write_error(refused, name, wanted[name].describe())


def _write_error(exc: S7Error, channel: str, address: str) -> DriverError:
    code = _s7_code(exc)
    if code in _ADDRESS_CODES or code in _ADDRESS_HEADER_CODES:
        return BadAddress(f"controller refused the write: {exc}", channel=channel,
                          address=address)
    permanent = code == 0x03  # access denied
    return WriteRejected(f"controller refused the write: {exc}", channel=channel,
                         address=address, permanent=permanent)


__all__ = ["S7Driver", "parse_endpoint"]
