"""A fault-injecting TCP proxy on 127.0.0.1 for the "slow controller" tests.

`FaultProxy` listens on a free loopback port and forwards every accepted
connection to a target (a simulated controller). Its mode can be switched at
run time; a switch applies at once to every open connection and to the ones
accepted later:

- ``pass_through()``: forward as received.
- ``latency(up_s, down_s)``: hold each chunk for the given delay per
  direction (``up`` = client -> server), in order; a chunk is stamped when it
  arrives, so data already held keeps its delay after a switch back to pass.
- ``reset()``: every open connection is reset (RST: ``SO_LINGER`` 0, then
  close) on both sides; new connections are accepted and reset at once.
- ``blackhole()``: connections are kept (and new ones accepted) but nothing is
  forwarded: what arrives is read, counted and dropped. A connection that was
  blackholed stays dead after the switch back to pass (as after a long
  outage: the lost bytes broke its stream); new connections work again.
- ``slow_start(per_chunk_s, chunks)``: every connection accepted from now on
  holds each of its first `chunks` client -> server chunks `per_chunk_s`
  longer (a handshake of several round trips, each well inside a request
  timeout, that takes longer as a whole than a fast cycle); its later chunks,
  and the connections already open, pass as received.
- ``cut_after(k_bytes, direction)``: each connection may forward `k_bytes`
  more in `direction` (``up``, ``down`` or ``both``), counted from the switch
  (or from its start when opened later); then it is closed (FIN) on both sides.

Counters: bytes forwarded per direction, connections accepted and open, and,
when a `frame_length` function is given, the client -> server frames as
received (`frames_received`) and as forwarded to the server (`frames_forwarded`).

A connection ends when either side closes or fails (after the data held for
that direction has been delivered); its sockets are closed then and its tasks
end, so after the client closes, the proxy holds nothing for it. `stop()`
closes the listener and every connection and leaves no task behind.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

Direction = Literal["up", "down"]
CutDirection = Literal["up", "down", "both"]
#: frame_length(buffer) -> the length of the frame starting the buffer, or None
#: while its header is incomplete
FrameLength = Callable[[bytes], int | None]

_CHUNK = 65536
#: how long the proxy waits for the target's TCP accept
_UPSTREAM_CONNECT_S = 2.0


def _abort_with_rst(writer: asyncio.StreamWriter) -> None:
    """Close a connection with a TCP RST (linger on, timeout 0)."""
    sock = writer.get_extra_info("socket")
    if sock is not None:
        with contextlib.suppress(OSError):
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    writer.transport.abort()


class _Framer:
    """Cuts a byte stream into frames with `frame_length`."""

    def __init__(self, frame_length: FrameLength, sink: list[bytes]) -> None:
        self._frame_length = frame_length
        self._sink = sink
        self._buf = b""

    def feed(self, data: bytes) -> None:
        self._buf += data
        while self._buf:
            n = self._frame_length(self._buf)
            if n is None or n > len(self._buf):
                return
            n = max(n, 1)  # a malformed header must not stall the loop
            self._sink.append(self._buf[:n])
            self._buf = self._buf[n:]


@dataclass(eq=False)  # identity hash: kept in a set
class _Conn:
    client: asyncio.StreamWriter
    server: asyncio.StreamWriter
    poisoned: bool = False
    #: bytes it may still forward in `budget_direction`; None: unlimited
    budget: int | None = None
    budget_direction: CutDirection = "down"
    finished: asyncio.Event = field(default_factory=asyncio.Event)
    rst: bool = False
    #: (extra hold, client -> server chunks it still applies to): `slow_start`
    slow: tuple[float, int] = (0.0, 0)


class FaultProxy:
    """See the module docstring."""

    def __init__(self, target_host: str, target_port: int, *, host: str = "127.0.0.1",
                 frame_length: FrameLength | None = None) -> None:
        self.target_host = target_host
        self.target_port = target_port
        self.host = host
        self.port = 0
        self._frame_length = frame_length
        self.mode: str = "pass"
        self._delay_s: dict[Direction, float] = {"up": 0.0, "down": 0.0}
        self._cut: tuple[int, CutDirection] | None = None
        self._slow: tuple[float, int] = (0.0, 0)
        self._server: asyncio.Server | None = None
        self._conns: set[_Conn] = set()
        self._handlers: set[asyncio.Task[None]] = set()
        #: bytes forwarded, per direction
        self.bytes_forwarded: dict[Direction, int] = {"up": 0, "down": 0}
        self.connections_accepted = 0
        self.frames_received: list[bytes] = []
        self.frames_forwarded: list[bytes] = []

    # -- lifecycle -------------------------------------------------------------

    async def start(self) -> None:
        if self._server is not None:
            return
        self._server = await asyncio.start_server(self._handle, self.host, 0)
        self.port = int(self._server.sockets[0].getsockname()[1])

    async def stop(self) -> None:
        server, self._server = self._server, None
        if server is None:
            return
        server.close()
        handlers = list(self._handlers)
        for task in handlers:
            task.cancel()
        await asyncio.gather(*handlers, return_exceptions=True)
        await server.wait_closed()

    async def __aenter__(self) -> FaultProxy:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()

    @property
    def open_connections(self) -> int:
        return len(self._conns)

    async def wait_idle(self, timeout_s: float) -> bool:
        """Wait until no connection is open (held data delivered, sockets
        closed, tasks ended); False if that did not happen within `timeout_s`."""
        for _ in range(max(1, round(timeout_s / 0.01))):
            if not self._handlers:
                return True
            await asyncio.sleep(0.01)
        return not self._handlers

    # -- modes -----------------------------------------------------------------

    def pass_through(self) -> None:
        self.mode = "pass"
        self._delay_s = {"up": 0.0, "down": 0.0}
        self._cut = None
        self._slow = (0.0, 0)

    def latency(self, up_s: float, down_s: float | None = None) -> None:
        if up_s < 0 or (down_s is not None and down_s < 0):
            raise ValueError("latency must be >= 0")
        self.pass_through()
        self.mode = "latency"
        self._delay_s = {"up": up_s, "down": up_s if down_s is None else down_s}

    def slow_start(self, per_chunk_s: float, chunks: int) -> None:
        if per_chunk_s < 0 or chunks < 0:
            raise ValueError("per_chunk_s and chunks must be >= 0")
        self.pass_through()
        self.mode = "slow_start"
        self._slow = (per_chunk_s, chunks)

    def reset(self) -> None:
        self.pass_through()
        self.mode = "reset"
        for conn in list(self._conns):
            self._reset(conn)

    def blackhole(self) -> None:
        self.pass_through()
        self.mode = "blackhole"
        for conn in self._conns:
            conn.poisoned = True

    def cut_after(self, k_bytes: int, direction: CutDirection = "down") -> None:
        if k_bytes < 0:
            raise ValueError("k_bytes must be >= 0")
        self.pass_through()
        self.mode = "cut"
        self._cut = (k_bytes, direction)
        for conn in self._conns:
            conn.budget, conn.budget_direction = k_bytes, direction

    # -- counters --------------------------------------------------------------

    def count_frames(self, predicate: Callable[[bytes], bool], *,
                     forwarded: bool = False) -> int:
        frames = self.frames_forwarded if forwarded else self.frames_received
        return sum(1 for f in frames if predicate(f))

    # -- connections -----------------------------------------------------------

    def _reset(self, conn: _Conn) -> None:
        conn.rst = True
        _abort_with_rst(conn.client)
        _abort_with_rst(conn.server)
        conn.finished.set()

    async def _handle(self, c_reader: asyncio.StreamReader,
                      c_writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        if task is not None:
            self._handlers.add(task)
        self.connections_accepted += 1
        try:
            if self.mode == "reset":
                _abort_with_rst(c_writer)
                return
            try:
                s_reader, s_writer = await asyncio.wait_for(
                    asyncio.open_connection(self.target_host, self.target_port),
                    _UPSTREAM_CONNECT_S)
            except (OSError, TimeoutError):
                _abort_with_rst(c_writer)
                return
            conn = _Conn(client=c_writer, server=s_writer, poisoned=self.mode == "blackhole",
                         slow=self._slow)
            if self._cut is not None:
                conn.budget, conn.budget_direction = self._cut
            await self._run(conn, c_reader, s_reader)
        except asyncio.CancelledError:
            # stop() cancels handlers; asyncio's stream callback would log a
            # cancelled handler as an error, and nothing awaits this task
            pass
        finally:
            if task is not None:
                self._handlers.discard(task)

    async def _run(self, conn: _Conn, c_reader: asyncio.StreamReader,
                   s_reader: asyncio.StreamReader) -> None:
        self._conns.add(conn)
        up: asyncio.Queue[tuple[float, bytes] | None] = asyncio.Queue()
        down: asyncio.Queue[tuple[float, bytes] | None] = asyncio.Queue()
        received = (_Framer(self._frame_length, self.frames_received)
                    if self._frame_length else None)
        forwarded = (_Framer(self._frame_length, self.frames_forwarded)
                     if self._frame_length else None)
        tasks = [
            asyncio.create_task(self._read(conn, "up", c_reader, up, received)),
            asyncio.create_task(self._send(conn, "up", up, conn.server, forwarded)),
            asyncio.create_task(self._read(conn, "down", s_reader, down, None)),
            asyncio.create_task(self._send(conn, "down", down, conn.client, None)),
        ]
        try:
            await conn.finished.wait()
        finally:
            self._conns.discard(conn)
            for t in tasks:
                t.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            for writer in (conn.client, conn.server):
                if not conn.rst:
                    writer.close()
            for writer in (conn.client, conn.server):
                with contextlib.suppress(OSError, asyncio.CancelledError):
                    await writer.wait_closed()

    async def _read(self, conn: _Conn, direction: Direction, reader: asyncio.StreamReader,
                    queue: asyncio.Queue[tuple[float, bytes] | None],
                    framer: _Framer | None) -> None:
        try:
            while True:
                data = await reader.read(_CHUNK)
                if not data:
                    break
                if framer is not None:
                    framer.feed(data)
                if conn.poisoned:
                    continue
                delay_s = self._delay_s[direction]
                extra_s, left = conn.slow
                if direction == "up" and left > 0:
                    delay_s += extra_s
                    conn.slow = (extra_s, left - 1)
                queue.put_nowait((time.monotonic() + delay_s, data))
        except OSError:
            pass
        finally:
            queue.put_nowait(None)

    async def _send(self, conn: _Conn, direction: Direction,
                    queue: asyncio.Queue[tuple[float, bytes] | None],
                    writer: asyncio.StreamWriter, framer: _Framer | None) -> None:
        try:
            while True:
                item = await queue.get()
                if item is None:
                    return
                due_s, data = item
                wait_s = due_s - time.monotonic()
                if wait_s > 0:
                    await asyncio.sleep(wait_s)
                if conn.poisoned:
                    continue
                cut = False
                if conn.budget is not None and conn.budget_direction in (direction, "both"):
                    if len(data) >= conn.budget:
                        data, cut = data[:conn.budget], True
                    conn.budget -= len(data)
                if data:
                    writer.write(data)
                    self.bytes_forwarded[direction] += len(data)
                    if framer is not None:
                        framer.feed(data)
                    await writer.drain()
                if cut:
                    return
        except OSError:
            pass
        finally:
            conn.finished.set()
