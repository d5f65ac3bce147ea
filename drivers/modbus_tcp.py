"""Modbus TCP client: the frames of the three requests the driver makes (0x03 read
holding registers, 0x04 read input registers, 0x10 write multiple registers) on
an asyncio protocol, one request in flight per connection.

A frame is the MBAP header (transaction id, protocol id 0, length, unit) and
the PDU (function code, then its fields), big-endian. A request: its frame
written, a future that the answer with its transaction id fulfils, one timer
of `timeout_s`. Then:

- an answer: the registers read (0x03/0x04) or nothing (0x10), or the
  controller's exception code (function code + 0x80), as a `Reply`;
- no answer in time: TimeoutError (the caller drops the connection: a late
  answer must never be taken for the next request's);
- the connection closed under the request: ConnectionError at once, not at
  the timeout;
- a frame that cannot be the answer (another transaction id, unit or
  function, a malformed length or byte count): the connection is closed and
  the request fails with ConnectionError (transaction id 0, and any unit to
  a request for unit 0, are taken, as pymodbus's client takes them: devices
  that answer so exist);
- the request cancelled (its caller's deadline): the connection is closed,
  for the same reason as a timeout.

Why not pymodbus's client (it serves the simulated controllers; the frames
are the standard's): per request it ran a transaction manager (a lock, PDU
objects, frame tracing kept for debugging, `asyncio.wait_for` with a timer of
its own) that cost about as much CPU as the socket I/O itself; with a
thousand machines in one process the driver was half of what a cycle cost
(`benchmarks/bench_driver_modbus.py` prints the CPU per cycle against the
bare pymodbus client; docs/operation.md, several machines in one process).
"""

from __future__ import annotations

import asyncio
import struct
from collections.abc import Coroutine
from typing import Any, NamedTuple

__all__ = ["READ_HOLDING", "READ_INPUT", "WRITE_MULTIPLE", "ModbusTcpClient", "Reply"]

READ_HOLDING = 0x03
READ_INPUT = 0x04
WRITE_MULTIPLE = 0x10
#: the largest MBAP length field: the unit byte and a PDU of at most 253 bytes
MAX_LENGTH = 254

_MBAP = struct.Struct(">HHHB")
_READ = struct.Struct(">BHH")
_WRITE = struct.Struct(">BHHB")
#: one Struct per register count (">nH"), made when a count is first seen
_WORDS: dict[int, struct.Struct] = {}


def _words(n: int) -> struct.Struct:
    s = _WORDS.get(n)
    if s is None:
        s = _WORDS[n] = struct.Struct(f">{n}H")
    return s


class Reply(NamedTuple):
    """A controller's answer: `exception_code` 0 and the registers read (none for a
    write), or the exception code it answered with (and no registers)."""

    exception_code: int
    registers: tuple[int, ...]


_WRITTEN = Reply(0, ())


def _expire(future: asyncio.Future[Reply], timeout_s: float) -> None:
    if not future.done():
        future.set_exception(TimeoutError(f"no answer within {timeout_s} s"))


class ModbusTcpClient(asyncio.Protocol):
    """One TCP connection to a Modbus server (see the module docstring)."""

    def __init__(self, timeout_s: float) -> None:
        if not timeout_s > 0:
            raise ValueError("timeout_s must be positive")
        self.timeout_s = timeout_s
        self._transport: asyncio.Transport | None = None
        self._buffer = bytearray()
        self._tid = 0
        #: the request in flight: transaction id, unit, function code, its future
        self._pending: tuple[int, int, int, asyncio.Future[Reply]] | None = None

    @classmethod
    async def open(cls, host: str, port: int, timeout_s: float) -> ModbusTcpClient:
        """Connected to host:port (OSError when refused; the caller bounds the time)."""
        loop = asyncio.get_running_loop()
        _, client = await loop.create_connection(lambda: cls(timeout_s), host, port)
        return client

    @property
    def connected(self) -> bool:
        t = self._transport
        return t is not None and not t.is_closing()

    def close(self) -> None:
        """Close the connection; a request in flight fails with ConnectionError."""
        t, self._transport = self._transport, None
        if t is not None:
            t.close()
        self._fail(ConnectionError("connection closed"))

    # -- requests -------------------------------------------------------------------

    def read_registers(self, unit: int, function: int, start: int,
                       count: int) -> Coroutine[Any, Any, Reply]:
        """Read `count` registers from `start` (`READ_HOLDING` or `READ_INPUT`)."""
        return self._request(unit, function, _READ.pack(function, start, count))

    def write_registers(self, unit: int, start: int,
                        words: list[int]) -> Coroutine[Any, Any, Reply]:
        """Write `words` (each 0..65535) from register `start` in one request."""
        n = len(words)
        pdu = _WRITE.pack(WRITE_MULTIPLE, start, n, 2 * n) + _words(n).pack(*words)
        return self._request(unit, WRITE_MULTIPLE, pdu)

    async def _request(self, unit: int, function: int, pdu: bytes) -> Reply:
        t = self._transport
        if t is None or t.is_closing():
            raise ConnectionError("not connected")
        if self._pending is not None:
            raise RuntimeError("a Modbus request is already in flight on this connection")
        self._tid = tid = self._tid % 0xFFFF + 1
        loop = asyncio.get_running_loop()
        future: asyncio.Future[Reply] = loop.create_future()
        pending = self._pending = (tid, unit, function, future)
        t.write(_MBAP.pack(tid, 0, len(pdu) + 1, unit) + pdu)
        timer = loop.call_later(self.timeout_s, _expire, future, self.timeout_s)
        try:
            return await future
        except (TimeoutError, asyncio.CancelledError):
            self._abort()  # the answer may still come: never for the next request
            raise
        finally:
            timer.cancel()
            if self._pending is pending:
                self._pending = None

    def _abort(self) -> None:
        """Close the connection without failing anything (nothing is in flight)."""
        t, self._transport = self._transport, None
        if t is not None:
            t.close()

    def _fail(self, exc: BaseException) -> None:
        pending, self._pending = self._pending, None
        if pending is not None and not pending[3].done():
            pending[3].set_exception(exc)

    # -- asyncio.Protocol ----------------------------------------------------------------

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self._transport = transport

    def connection_lost(self, exc: Exception | None) -> None:
        self._transport = None
        self._fail(ConnectionError(f"connection closed by the controller"
                                   f"{': ' + str(exc) if exc else ''}"))

    def data_received(self, data: bytes) -> None:
        buf = self._buffer
        if not buf and len(data) >= 7 and len(data) == 6 + ((data[4] << 8) | data[5]):
            self._frame(data)  # the usual case: one whole answer in one segment
            return
        buf += data
        while len(buf) >= 7:
            length = (buf[4] << 8) | buf[5]
            if not 2 <= length <= MAX_LENGTH:
                self._protocol_error(f"MBAP length {length} out of range")
                return
            if len(buf) < 6 + length:
                return
            frame = bytes(buf[:6 + length])
            del buf[:6 + length]
            self._frame(frame)

    def _frame(self, frame: bytes) -> None:
        pending = self._pending
        if pending is None or pending[3].done():
            return  # nothing asked (an answer after a cancel is never taken)
        tid, unit, function, future = pending
        got_tid, protocol, _, got_unit = _MBAP.unpack_from(frame)
        # as pymodbus's client: a device that answers every request with transaction 0,
        # and a gateway addressed as unit 0 that answers as another, are taken
        if (got_tid not in (tid, 0) or protocol != 0
                or unit not in (got_unit, 0)):
            self._protocol_error(f"answer for transaction {got_tid} unit {got_unit} "
                                 f"(protocol {protocol}) while {tid} unit {unit} is asked")
            return
        code = frame[7] if len(frame) > 7 else -1
        if code == function | 0x80:
            if len(frame) != 9 or frame[8] == 0:
                self._protocol_error(f"exception answer of {len(frame)} bytes")
                return
            reply = Reply(frame[8], ())
        elif code != function:
            self._protocol_error(f"answer with function {code} to function {function}")
            return
        elif function == WRITE_MULTIPLE:
            reply = _WRITTEN
        else:
            count = frame[8] if len(frame) > 8 else -1
            if count < 0 or count % 2 or len(frame) != 9 + count:
                self._protocol_error(f"read answer of {len(frame)} bytes with byte "
                                     f"count {count}")
                return
            reply = Reply(0, _words(count // 2).unpack_from(frame, 9))
        self._pending = None
        future.set_result(reply)

    def _protocol_error(self, why: str) -> None:
        self._buffer.clear()
        self._fail(ConnectionError(f"not a Modbus answer: {why}"))
        self._abort()
