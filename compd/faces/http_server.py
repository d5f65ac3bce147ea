"""A bounded HTTP/1.1 server for the faces (/metrics, the operator page, /status.json).

The standard library's threading servers start a thread per connection: 800
sockets that each send half a request head make 803 threads, and under the
shipped unit's ``TasksMax=64`` the daemon then cannot start the thread a
reload needs. This server has a fixed number of threads whatever the clients
do: one I/O thread (a `selectors` loop that accepts, reads request heads and
writes answers, all non-blocking) and `HttpLimits.workers` threads that run
the WSGI application (prometheus_client's exposition, the status page), all
started by `start` and none later.

Its bounds (`HttpLimits`), and how hitting one is counted and logged
(`LimitCounter`): `compd.faces.http_limits`.

Time comes from `clock` (monotonic seconds; tests pass a fake one and call
`wake` after advancing it). The HTTP itself (parsing a head, the WSGI call,
error answers) is `compd.faces.http_wire`, without sockets or threads.
"""

from __future__ import annotations

import contextlib
import queue
import selectors
import socket
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from compd.faces import http_limits as bounds
from compd.faces.http_limits import REASONS, HttpLimits, LimitCounter, limits_from
from compd.faces.http_wire import BadRequest, WSGIApp, environ, error_answer, parse_request, run_app

__all__ = ["REASONS", "HttpLimits", "HttpServer", "WSGIApp", "limits_from"]

_READ_CHUNK = 4096


# connection phases
_HEAD, _BUSY, _WRITE = "head", "busy", "write"


@dataclass(eq=False)
class _Conn:
    sock: socket.socket
    peer: str
    deadline: float
    phase: str = _HEAD
    buf: bytearray = field(default_factory=bytearray)
    out: bytes = b""
    sent: int = 0
    keep_alive: bool = False
    fresh: bool = True  # no byte of the current request yet


@dataclass
class _Job:
    """A request for a worker: the connection it came on and its WSGI environ."""

    conn: _Conn
    environ: dict[str, Any]
    head: bool
    keep_alive: bool


class HttpServer:
    """`app` served on host:port with a fixed number of threads; see the module docstring.

    The socket is bound in the constructor (OSError: the port is taken);
    `start` starts the threads, `stop` closes everything and joins them."""

    def __init__(self, app: WSGIApp, host: str, port: int, limits: HttpLimits | None = None,
                 *, clock: Callable[[], float] = time.monotonic,
                 on_count: Callable[[str], None] | None = None) -> None:
        self.app = app
        self.limits = limits if limits is not None else HttpLimits()
        self.clock = clock
        self._counter = LimitCounter(clock, on_count)
        #: connections closed early or answered with an error, by reason (`REASONS`)
        self.counts = self._counter.counts
        self.served = 0
        info = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
        family, _, _, _, address = info[0]
        sock = socket.socket(family, socket.SOCK_STREAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind(address)
            sock.listen(bounds.BACKLOG)
            sock.setblocking(False)
        except BaseException:
            sock.close()
            raise
        self._listener = sock
        self.host = host
        self.port = int(sock.getsockname()[1])
        self._selector = selectors.DefaultSelector()
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)
        self._conns: set[_Conn] = set()
        #: the connections waiting for a request head, longest waiting first
        self._waiting: dict[_Conn, None] = {}
        self._requests: queue.SimpleQueue[_Job | None] = queue.SimpleQueue()
        self._answers: deque[tuple[_Conn, bytes, bool]] = deque()
        self._stopping = threading.Event()
        self._accept_paused_until: float | None = None
        self._threads: list[threading.Thread] = []

    # -- life -------------------------------------------------------------------------

    @property
    def open_connections(self) -> int:
        return len(self._conns)

    @property
    def threads(self) -> list[threading.Thread]:
        """The server's threads (fixed at `start`)."""
        return list(self._threads)

    def start(self) -> None:
        if self._threads:
            raise RuntimeError("already started")
        self._selector.register(self._listener, selectors.EVENT_READ, "listen")
        self._selector.register(self._wake_r, selectors.EVENT_READ, "wake")
        threads = [threading.Thread(target=self._io_loop, name="compd-http", daemon=True)]
        threads += [threading.Thread(target=self._worker, name=f"compd-http-worker-{i}",
                                     daemon=True) for i in range(self.limits.workers)]
        for t in threads:
            t.start()
        self._threads = threads

    def wake(self) -> None:
        """Make the I/O thread look at its deadlines now (after a fake clock moved)."""
        with contextlib.suppress(OSError):
            self._wake_w.send(b"\0")

    def stop(self, timeout_s: float = 5.0) -> None:
        """Close the listener and every connection (the I/O thread does, as it ends);
        join the threads. A worker still inside the application ends when it
        returns. Idempotent."""
        self._stopping.set()
        self.wake()
        for _ in range(self.limits.workers):
            self._requests.put(None)
        if not self._threads:  # never started: nobody else owns the sockets
            self._close_all()
        else:
            io_thread, *workers = self._threads
            io_thread.join(timeout=timeout_s)
            give_up = time.monotonic() + 1.0
            for t in workers:
                t.join(timeout=max(0.0, give_up - time.monotonic()))
        with contextlib.suppress(OSError):
            self._wake_w.close()

    def _close_all(self) -> None:
        for conn in list(self._conns):
            self._close(conn)
        for s in (self._listener, self._wake_r):
            with contextlib.suppress(OSError):
                s.close()
        with contextlib.suppress(OSError, ValueError):
            self._selector.close()

    # -- counting and logging -----------------------------------------------------------

    def _count(self, reason: str, peer: str = "", **detail: Any) -> None:
        self._counter.count(reason, peer, open_connections=len(self._conns), **detail)

    # -- the I/O thread ------------------------------------------------------------------

    def _io_loop(self) -> None:
        try:
            while not self._stopping.is_set():
                try:
                    self._io_once()
                except Exception as exc:  # never a traceback, never the loop's end
                    self._count("server_error", error=f"{type(exc).__name__}: {exc}")
                    self._stopping.wait(0.05)  # not a hot loop if it happens again at once
        finally:
            self._close_all()  # the port is free once this thread has ended

    def _io_once(self) -> None:
        now = self.clock()
        timeout = self._next_deadline(now)
        for key, mask in self._selector.select(timeout):
            tag = key.data
            if tag == "listen":
                self._accept()
            elif tag == "wake":
                with contextlib.suppress(OSError):
                    while self._wake_r.recv(4096):
                        pass
            elif isinstance(tag, _Conn) and tag in self._conns:
                if mask & selectors.EVENT_READ:
                    self._read(tag)
                elif mask & selectors.EVENT_WRITE:
                    self._write(tag)
        while self._answers:
            conn, data, keep_alive = self._answers.popleft()
            if conn in self._conns:
                self._answer(conn, data, keep_alive)
        self._expire(self.clock())

    def _next_deadline(self, now: float) -> float | None:
        deadlines = [c.deadline for c in self._conns if c.phase != _BUSY]
        if self._accept_paused_until is not None:
            deadlines.append(self._accept_paused_until)
        if not deadlines:
            return None
        return max(0.0, min(min(deadlines) - now, 1.0))

    def _expire(self, now: float) -> None:
        if self._accept_paused_until is not None and now >= self._accept_paused_until:
            self._accept_paused_until = None
            with contextlib.suppress(KeyError, ValueError, OSError):
                self._selector.register(self._listener, selectors.EVENT_READ, "listen")
        for conn in [c for c in self._conns if c.phase != _BUSY and now >= c.deadline]:
            if conn.phase == _WRITE:
                reason = "idle_timeout"
            else:
                reason = "idle_timeout" if conn.fresh and conn.keep_alive else "header_timeout"
            self._count(reason, conn.peer)
            self._close(conn)

    def _accept(self) -> None:
        for _ in range(bounds.ACCEPT_BATCH):
            try:
                sock, addr = self._listener.accept()
            except BlockingIOError:
                return
            except OSError as exc:
                if exc.errno in bounds.ACCEPT_OUT_OF_RESOURCES:
                    self._count("accept_failed", error=exc.strerror or str(exc))
                    victim = self._oldest_waiting()
                    if victim is not None:
                        self._close(victim)
                    self._accept_paused_until = self.clock() + bounds.ACCEPT_PAUSE_S
                    with contextlib.suppress(KeyError, ValueError):
                        self._selector.unregister(self._listener)
                return  # ECONNABORTED and the like: the client is gone
            peer = _peer(addr)
            try:
                sock.setblocking(False)
            except OSError:
                sock.close()
                continue
            if len(self._conns) >= self.limits.max_connections:
                victim = self._oldest_waiting()
                if victim is None:
                    self._count("refused", peer)
                    _send_quietly(sock, error_answer(503, "too many connections"))
                    sock.close()
                    continue
                self._count("evicted", victim.peer)
                self._close(victim)
            now = self.clock()
            conn = _Conn(sock=sock, peer=peer, deadline=now + self.limits.header_timeout_s)
            try:
                self._selector.register(sock, selectors.EVENT_READ, conn)
            except (OSError, ValueError):
                sock.close()
                continue
            self._conns.add(conn)
            self._waiting[conn] = None
            # a real client sent its request with its connect: read it now, before newer
            # connections can make this one the oldest waiting (and close it)
            self._read(conn)

    def _oldest_waiting(self) -> _Conn | None:
        return next(iter(self._waiting), None)

    def _close(self, conn: _Conn) -> None:
        self._conns.discard(conn)
        self._waiting.pop(conn, None)
        with contextlib.suppress(KeyError, ValueError, OSError):
            self._selector.unregister(conn.sock)
        with contextlib.suppress(OSError):
            conn.sock.close()

    def _read(self, conn: _Conn) -> None:
        try:
            data = conn.sock.recv(_READ_CHUNK)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            self._close(conn)
            return
        if not data:
            self._close(conn)  # the client closed (or gave up)
            return
        if conn.fresh:
            conn.fresh = False
            if conn.keep_alive:  # a kept-alive connection's next request: the head's clock
                conn.deadline = self.clock() + self.limits.header_timeout_s
        conn.buf += data
        self._try_request(conn)

    def _try_request(self, conn: _Conn) -> None:
        try:
            request = parse_request(conn.buf, self.limits.max_head_bytes)
        except BadRequest as exc:
            self._count(exc.reason, conn.peer, error=str(exc))
            self._answer(conn, error_answer(exc.code, str(exc)), False)
            return
        if request is None:
            return
        conn.phase = _BUSY
        self._waiting.pop(conn, None)
        with contextlib.suppress(KeyError, ValueError):
            self._selector.unregister(conn.sock)
        env = environ(request, self.host, self.port, conn.peer.rpartition(":")[0])
        self._requests.put(_Job(conn, env, request.method == "HEAD", request.keep_alive))

    def _answer(self, conn: _Conn, data: bytes, keep_alive: bool) -> None:
        """Start writing `data`; then keep the connection for the next request or close."""
        conn.phase, conn.out, conn.sent, conn.keep_alive = _WRITE, data, 0, keep_alive
        self._waiting.pop(conn, None)
        conn.deadline = self.clock() + self.limits.idle_timeout_s
        try:
            self._selector.modify(conn.sock, selectors.EVENT_WRITE, conn)
        except KeyError:
            try:
                self._selector.register(conn.sock, selectors.EVENT_WRITE, conn)
            except (OSError, ValueError):
                self._close(conn)
                return
        except (OSError, ValueError):
            self._close(conn)
            return
        self._write(conn)

    def _write(self, conn: _Conn) -> None:
        try:
            while conn.sent < len(conn.out):
                n = conn.sock.send(memoryview(conn.out)[conn.sent:conn.sent + 65536])
                conn.sent += n
        except (BlockingIOError, InterruptedError):
            return  # the selector says when the client reads on
        except OSError as exc:
            self._count("write_failed", conn.peer, error=exc.strerror or str(exc))
            self._close(conn)
            return
        self.served += 1
        if not conn.keep_alive or self._stopping.is_set():
            self._close(conn)
            return
        now = self.clock()
        conn.phase, conn.out, conn.fresh = _HEAD, b"", True
        conn.deadline = now + self.limits.idle_timeout_s
        self._waiting[conn] = None  # the newest waiting
        try:
            self._selector.modify(conn.sock, selectors.EVENT_READ, conn)
        except (KeyError, OSError, ValueError):
            self._close(conn)
            return
        if conn.buf:  # a request sent right behind the last one
            conn.fresh = False
            conn.deadline = now + self.limits.header_timeout_s
            self._try_request(conn)

    # -- the workers ----------------------------------------------------------------------

    def _worker(self) -> None:
        while True:
            request = self._requests.get()
            if request is None or self._stopping.is_set():
                return
            try:
                data = run_app(self.app, request.environ, head=request.head,
                               keep_alive=request.keep_alive)
                keep_alive = request.keep_alive
            except Exception as exc:  # this request fails, nothing else
                self._count("app_error", request.conn.peer,
                            error=f"{type(exc).__name__}: {exc}")
                data, keep_alive = error_answer(500, "internal error"), False
            self._answers.append((request.conn, data, keep_alive))
            self.wake()

def _peer(addr: Any) -> str:
    if isinstance(addr, tuple) and len(addr) >= 2:
        return f"{addr[0]}:{addr[1]}"
    return str(addr)


def _send_quietly(sock: socket.socket, data: bytes) -> None:
    """Best effort on a socket about to be closed: what the client sent already is
    read first (unread data would turn the close into a reset that hides the answer)."""
    with contextlib.suppress(OSError):
        sock.recv(65536)
    with contextlib.suppress(OSError):
        sock.send(data)
        sock.shutdown(socket.SHUT_WR)
