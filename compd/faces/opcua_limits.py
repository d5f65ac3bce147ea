"""The OPC UA face's limits (`compd.faces.opcua_face`): connections, sessions,
handshake time, file descriptors, and failed logins told without flooding.

- **Connections**: at most ``max_connections`` TCP connections at once, fewer
  when the process's file descriptor limit leaves less (`fd_budget`: the soft
  RLIMIT_NOFILE minus what is open at start, `FD_RESERVE` kept for the cycle,
  its checkpoints, the recorder, /metrics and controller reconnects, and
  `ACCEPT_BURST`, what one wake of the listener may accept before it refuses).
  A new connection at the limit evicts one that has no session yet
  (`Guard.victim`): the oldest that has not sent a byte (nor has one waiting
  in the kernel); else the oldest that spoke but is still without a session
  half its ``handshake_timeout_s`` after it was accepted (a handshake stalled
  on purpose). Never one with a session, one in its handshake for less than
  that, or one accepted so recently that the loop could not read it yet (its
  transport is not made): a real client sends its Hello with its connect, so
  sockets that send nothing cannot keep the operator out, nor push out one
  that is logging in. When no connection may be evicted, the new one is
  closed at once (no OPC UA answer, no traceback). Both are counted
  (``compd_opcua_face_connections_refused_total{reason="evicted"|"limit"}``)
  and logged rate-limited (``opcua_connection_refused``). So the face never
  brings the process to EMFILE, and asyncio never logs "socket.accept() out of
  system resource".
- **Handshake**: a connection that has not activated a session
  ``handshake_timeout_s`` after it was accepted is closed (reason
  ``handshake_timeout``).
- **Sessions**: at most ``max_sessions`` activated sessions; one more is
  refused with BadTooManySessions (``opcua_session_refused``, reason
  ``max_sessions``). With an operator, anonymous sessions take at most
  `Guard.anonymous_limit`: ``max_sessions`` minus ``reserved_sessions``, so
  that the operator always gets one, and at most half the connections, so
  that logins keep room to get in (and be evicted last) while silent sockets
  take the rest (reason ``anonymous_share``).
- **Failed logins**: a wrong user name or password is logged with the user
  name and the client's address (``opcua_login_failed``; never the password)
  and counted (``compd_opcua_face_logins_failed_total``).

Every refusal is logged by `Tally`: the first `BURST` of a kind in a minute
one line each, then one summary line per minute with the count and the users
and peers seen most (``..._summary``).

How: the face's event loop is `FaceLoop`, whose ``create_server`` (what
asyncua's server calls to listen) wraps asyncua's protocol factory in
`Guard.factory`; each connection's protocol is asyncua's behind `_Tracked`,
which sets `CONNECTION` for the connection's tasks, so that the user manager
knows whose login it judges.

The descriptor budget is `compd.faces.fd_budget`, `Tally` `compd.faces.log_tally`, the
guard's metrics and asyncua's quieted line `compd.faces.opcua_guard_report`.
"""

from __future__ import annotations

import asyncio
import contextlib
import contextvars
import fcntl
import struct
import termios
import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import structlog
from asyncua.common.utils import ServiceError
from asyncua.ua.status_codes import StatusCodes

from compd.faces.fd_budget import ACCEPT_BURST, FD_RESERVE, fd_budget, nofile_soft_limit, open_fds
from compd.faces.log_tally import BURST, WINDOW_S, Tally

__all__ = ["ACCEPT_BURST", "BURST", "CONNECTION", "FD_RESERVE", "FaceLoop", "Guard", "Tally",
           "fd_budget", "pending_bytes"]

#: longest user name put in a log line
_USER_CHARS = 64


@dataclass(eq=False)  # one object per connection, kept in a set
class Connection:
    """One accepted connection: its peer, and whether it has a session yet."""

    peer: str
    transport: asyncio.Transport | None = None
    activated: bool = False
    #: the session is anonymous (counted against the anonymous share)
    anonymous: bool = False
    #: the client has sent at least one byte
    spoke: bool = False
    #: when it was accepted (the guard's clock)
    opened_at: float = 0.0
    #: the next service fault on this connection is one the face has logged itself
    quiet_fault: bool = False
    timer: asyncio.TimerHandle | None = None


#: the connection whose messages are being processed (set for its tasks)
CONNECTION: contextvars.ContextVar[Connection | None] = contextvars.ContextVar(
    "compd_opcua_connection", default=None)





def safe_user(name: str) -> str:
    """A client's user name as a log field: printable, at most 64 characters."""
    clean = "".join(c if c.isprintable() else "?" for c in name)
    return clean if len(clean) <= _USER_CHARS else clean[:_USER_CHARS] + "…"


class Guard:
    """The face's limits on one server (see the module docstring)."""

    def __init__(self, *, max_connections: int, max_sessions: int, handshake_timeout_s: float,
                 reserved_sessions: int = 0, log: Any = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.max_connections = max_connections
        self.limit = max_connections  # until `fit_to_descriptors`
        self.max_sessions = max_sessions
        #: sessions anonymous clients never take (0: no operator to keep them for)
        self.reserved_sessions = reserved_sessions
        self.handshake_timeout_s = handshake_timeout_s
        self.log = log if log is not None else structlog.get_logger("compd").bind(face="opcua")
        self.clock = clock
        #: the connections held, oldest first (a dict keeps the order they came in)
        self.connections: dict[Connection, None] = {}
        self.sessions = 0
        self.anonymous_sessions = 0
        self.refused: Counter[str] = Counter({"limit": 0, "evicted": 0, "handshake_timeout": 0})
        self.sessions_refused: Counter[str] = Counter({"max_sessions": 0, "anonymous_share": 0})
        self.tallies = {name: Tally(name, self.log, clock) for name in
                        ("opcua_connection_refused", "opcua_login_failed",
                         "opcua_session_refused")}

    def fit_to_descriptors(self, soft_limit: int | None = None,
                           open_now: int | None = None) -> int:
        """Lower the connection limit to the descriptors there are (at start);
        ValueError when not even one connection fits."""
        soft = nofile_soft_limit() if soft_limit is None else soft_limit
        now = open_fds() if open_now is None else open_now
        budget = fd_budget(soft, now)
        if budget < 1:
            raise ValueError(f"RLIMIT_NOFILE {soft} leaves no descriptor for a client "
                             f"({now} open, {FD_RESERVE} kept for the cycle): raise "
                             "LimitNOFILE")
        if budget < self.max_connections:
            self.log.warning("opcua_face_connections_capped", max_connections=budget,
                             configured=self.max_connections, rlimit_nofile=soft,
                             open_fds=now, reserve=FD_RESERVE)
        self.limit = min(self.max_connections, budget)
        return self.limit

    @property
    def anonymous_limit(self) -> int:
        """Anonymous sessions at most: all of them without an operator; with one,
        what the reserve leaves of the sessions, and half the connections."""
        if self.reserved_sessions == 0:
            return self.max_sessions
        return max(0, min(self.max_sessions - self.reserved_sessions, self.limit // 2))

    # -- connections ---------------------------------------------------------------

    def factory(self, inner: Callable[[], asyncio.Protocol]) -> Callable[[], asyncio.Protocol]:
        """asyncua's protocol factory behind the connection limit."""
        def make() -> asyncio.Protocol:
            if len(self.connections) >= self.limit:
                victim = self.victim()
                if victim is None:
                    return _Refused(self)
                self.evict(victim)
            conn = Connection(peer="unknown", opened_at=self.clock())
            self.connections[conn] = None  # counted from now: the accept burst is bounded
            return _Tracked(self, conn, inner())
        return make

    def victim(self) -> Connection | None:
        """The connection a new one replaces at the limit (see the module docstring):
        the oldest silent one, else the oldest whose handshake has stalled; None
        when every other has a session, is logging in, or is too new to be read."""
        stalled_before = self.clock() - self.handshake_timeout_s / 2.0
        stalled: Connection | None = None
        for conn in self.connections:
            transport = conn.transport
            if conn.activated or transport is None or transport.is_closing():
                continue
            if not conn.spoke and pending_bytes(transport) > 0:
                conn.spoke = True  # its first message is there, the loop has not read it yet
            if not conn.spoke:
                return conn
            if stalled is None and conn.opened_at <= stalled_before:
                stalled = conn
        return stalled

    def evict(self, conn: Connection) -> None:
        """Close `conn` now to make room (its slot is free at once)."""
        self.connections.pop(conn, None)
        if conn.timer is not None:
            conn.timer.cancel()
            conn.timer = None
        if conn.transport is not None:
            conn.transport.abort()
        self.refuse("evicted", conn.peer)

    def refuse(self, reason: str, peer: str) -> None:
        self.refused[reason] += 1
        self.tallies["opcua_connection_refused"].note(
            peer=peer, reason=reason, limit=self.limit,
            **({"timeout_s": self.handshake_timeout_s} if reason == "handshake_timeout" else {}))

    def _opened(self, conn: Connection) -> None:
        if self.handshake_timeout_s > 0:
            loop = asyncio.get_running_loop()
            conn.timer = loop.call_later(self.handshake_timeout_s, self._handshake_over, conn)

    def _handshake_over(self, conn: Connection) -> None:
        conn.timer = None
        transport = conn.transport
        if conn.activated or transport is None or transport.is_closing():
            return
        self.refuse("handshake_timeout", conn.peer)
        transport.abort()

    def _closed(self, conn: Connection) -> None:
        if conn.timer is not None:
            conn.timer.cancel()
            conn.timer = None
        if conn in self.connections:
            del self.connections[conn]
            if conn.activated:
                self.sessions = max(0, self.sessions - 1)
                if conn.anonymous:
                    self.anonymous_sessions = max(0, self.anonymous_sessions - 1)

    # -- logins (called by the user manager, in the connection's task) ------------

    def login_failed(self, user: str) -> None:
        conn = CONNECTION.get()
        peer = conn.peer if conn is not None else "unknown"
        if conn is not None:
            conn.quiet_fault = True
        self.tallies["opcua_login_failed"].note(user=safe_user(user), peer=peer)

    def login_ok(self, user: str, *, anonymous: bool = False) -> None:
        """A session is activated; BadTooManySessions (a ServiceError) over
        `max_sessions`, or for an anonymous one over `anonymous_limit`."""
        conn = CONNECTION.get()
        if conn is None or conn.activated:
            return  # asyncua's own session, or one connection activating again
        if self.sessions >= self.max_sessions:
            self._refuse_session(conn, user, "max_sessions", self.max_sessions)
        if anonymous and self.anonymous_sessions >= self.anonymous_limit:
            self._refuse_session(conn, user, "anonymous_share", self.anonymous_limit)
        conn.activated = True
        conn.anonymous = anonymous
        self.sessions += 1
        if anonymous:
            self.anonymous_sessions += 1

    def _refuse_session(self, conn: Connection, user: str, reason: str, limit: int) -> None:
        self.sessions_refused[reason] += 1
        conn.quiet_fault = True
        self.tallies["opcua_session_refused"].note(user=safe_user(user), peer=conn.peer,
                                                   reason=reason, limit=limit)
        raise ServiceError(StatusCodes.BadTooManySessions)

    def flush(self, *, force: bool = False) -> None:
        for tally in self.tallies.values():
            tally.flush(force=force)

    async def summarise(self) -> None:
        """On the face's loop: the summary lines, once per window."""
        while True:
            await asyncio.sleep(WINDOW_S / 4)
            self.flush()


def pending_bytes(transport: asyncio.BaseTransport) -> int:
    """Bytes the kernel holds for `transport`'s socket that were not read yet
    (FIONREAD); 0 when it cannot tell."""
    sock = transport.get_extra_info("socket")
    if sock is None:
        return 0
    try:
        raw = fcntl.ioctl(sock.fileno(), termios.FIONREAD, b"\0\0\0\0")
    except (OSError, ValueError):
        return 0
    return int(struct.unpack("i", raw)[0])


def _abort(transport: asyncio.BaseTransport) -> None:
    """Close at once, dropping anything unsent."""
    if isinstance(transport, asyncio.Transport):
        transport.abort()
    else:
        transport.close()


class _Refused(asyncio.Protocol):
    """A connection over the limit: closed as soon as it is made."""

    def __init__(self, guard: Guard) -> None:
        self.guard = guard

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        peer = str(transport.get_extra_info("peername"))
        _abort(transport)
        self.guard.refuse("limit", peer)


class _Tracked(asyncio.Protocol):
    """asyncua's protocol for one connection, counted, timed and known by its peer."""

    def __init__(self, guard: Guard, conn: Connection, inner: asyncio.Protocol) -> None:
        self.guard, self.conn, self.inner = guard, conn, inner

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.conn.peer = str(transport.get_extra_info("peername"))
        self.conn.transport = transport if isinstance(transport, asyncio.Transport) else None
        token = CONNECTION.set(self.conn)  # the tasks asyncua starts here copy it
        try:
            self.inner.connection_made(transport)
        finally:
            CONNECTION.reset(token)
        self.guard._opened(self.conn)

    def data_received(self, data: bytes) -> None:
        self.conn.spoke = True
        self.inner.data_received(data)

    def eof_received(self) -> bool | None:
        return self.inner.eof_received()

    def pause_writing(self) -> None:
        self.inner.pause_writing()

    def resume_writing(self) -> None:
        self.inner.resume_writing()

    def connection_lost(self, exc: Exception | None) -> None:
        self.guard._closed(self.conn)
        self.inner.connection_lost(exc)


class FaceLoop(asyncio.SelectorEventLoop):
    """The face's own event loop: servers it starts go through `guard`."""

    def __init__(self, guard: Guard) -> None:
        super().__init__()
        self.guard = guard

    # typeshed spells out every keyword of create_server; this passes them through
    # (*args/**kwargs) after wrapping the factory, which mypy takes for a narrower signature
    async def create_server(  # type: ignore[override]
            self, protocol_factory: Callable[[], asyncio.Protocol], *args: Any,
            **kwargs: Any) -> asyncio.Server:
        kwargs["backlog"] = ACCEPT_BURST
        return await super().create_server(self.guard.factory(protocol_factory), *args,
                                           **kwargs)


@contextlib.contextmanager
def connection(conn: Connection) -> Iterator[None]:
    """`conn` as the current connection (tests of the user manager)."""
    token = CONNECTION.set(conn)
    try:
        yield
    finally:
        CONNECTION.reset(token)
