"""The one connection lifecycle every driver shares (`Link`).

A driver owns one `Link`; the link owns the session (the protocol library's
client or handle) and decides, the same way for every protocol:

- **closed**: after `close()`, `read`/`write` raise `ConnectionLost` at once
  and never reconnect; only an explicit `connect()` opens the link again.
- **backoff gate**: while the link is down and `Backoff` says no attempt is
  due, a call fails fast with `ConnectionLost` without touching the network.
- **reconnect on the next call**: once an attempt is due, the next call opens
  a fresh session before it runs (an explicit `connect()` does not wait for
  the backoff delay).
- **a connect is its own task**: the open runs in a task of the link's, bounded
  by `connect_timeout_s` and by nothing else: the call that starts it waits for
  its outcome (so do calls made meanwhile), but when it gives up (the daemon
  bounds each cycle's read by its period) the connect goes on. A call that
  finds a connect in progress nobody waits for any more fails fast with
  `ConnectionLost` (the daemon's cycle holds, on time); the
  first call after it completes takes its session. An explicit `connect()`
  waits for it; only `close()` cancels it. (Were the connect bounded by its
  caller's deadline, one slower than a cycle would be cancelled by every
  cycle's read deadline, and the link would never come back.)
- **connect-failure wrapping**: a failed open starts the backoff delay; a
  timeout becomes `ControllerTimeout`, one of the driver's declared
  `connect_errors` becomes `ConnectionLost`, a `DriverError` passes as it is.
- **a failed call drops the link**: a `ConnectionLost` or a timeout out of a
  call drops the session and starts the backoff delay; a bare `TimeoutError`
  (or one of the driver's `timeout_errors`) becomes `ControllerTimeout`, one
  of its `lost_errors` becomes `ConnectionLost`. Any other error (a refused
  address, a refused write) leaves the link up.

What a session is, how it opens and how it is torn down is the driver's:
`open` and `drop` are its coroutines (a blocking library runs them on its
worker thread: `WorkerLink`). `drop(session, closing)` must not wait on a
hung controller unless `closing`.
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from functools import partial
from typing import Any, Generic, TypeVar

from drivers.backoff import Backoff
from drivers.deadline import deadline
from drivers.errors import Channels, ConnectionLost, ControllerTimeout, DriverError
from drivers.io_thread import IoThread

S = TypeVar("S")
T = TypeVar("T")


class Link(Generic[S]):
    """One controller link: its session, closed flag and backoff (see module)."""

    def __init__(self, endpoint: str, backoff: Backoff, timeout_s: float, *,
                 open: Callable[[], Awaitable[S]],
                 drop: Callable[[S, bool], Awaitable[None]],
                 connect_errors: tuple[type[BaseException], ...] = (OSError,),
                 timeout_errors: tuple[type[BaseException], ...] = (),
                 lost_errors: tuple[type[BaseException], ...] = (),
                 alive: Callable[[S], bool] | None = None,
                 connect_timeout_s: float | None = None) -> None:
        self.endpoint = endpoint
        self.backoff = backoff
        self.timeout_s = timeout_s
        #: the bound on one connect, whoever waits for it (a connect takes longer
        #: than a request: by default max(2·timeout_s, 1 s))
        self.connect_timeout_s = connect_timeout_s or max(2.0 * timeout_s, 1.0)
        self._open_session = open
        self._drop_session = drop
        self._connect_errors = connect_errors
        self._timeout_errors: tuple[type[BaseException], ...] = (TimeoutError, *timeout_errors)
        self._lost_errors = lost_errors
        self._alive = alive
        #: the connect in progress (`_attempt`), None when there is none
        self._connecting: asyncio.Task[S] | None = None
        #: calls waiting for it (none: its caller gave up, and a call fails fast)
        self._waiting = 0
        #: the open session, None while the link is down
        self.session: S | None = None
        self.closed = False

    @property
    def up(self) -> bool:
        s = self.session
        return s is not None and (self._alive is None or self._alive(s))

    async def connect(self) -> S:
        """Open the link now (also after `close()`), whatever the backoff says;
        waits for the connect in progress, if there is one."""
        self.closed = False
        return await self._open("connect", None, None, gate=False, join=True)

    async def ready(self, what: str = "call", channel: Channels = None,
                    address: str | None = None) -> S:
        """The session for a call: the open one, else a new one when the link
        is not closed, no connect is in progress and the backoff allows an
        attempt; else `ConnectionLost`."""
        s = self.session
        if s is not None:
            if self._alive is None or self._alive(s):
                return s
            await self.lost(s)  # the controller closed it since the last call
        return await self._open(what, channel, address, gate=True, join=False)

    async def _open(self, what: str, channel: Channels, address: str | None, *,
                    gate: bool, join: bool) -> S:
        """Start a connect and wait for its outcome. One in progress is waited
        for when `join` or while another call waits for it (calls made together);
        one that nobody waits for any more fails the call fast (see the module)."""
        if self.session is not None:
            return self.session
        task = self._connecting
        if task is not None and not join and not self._waiting:
            raise ConnectionLost(f"{self.endpoint} down; a connect is in progress "
                                 f"(up to {self.connect_timeout_s:g} s)",
                                 channel=channel, address=address)
        if task is None:
            if gate:
                self._gate(channel, address)
            task = self._connecting = asyncio.create_task(
                self._attempt(), name=f"connect {self.endpoint}")
            task.add_done_callback(self._attempted)
        # asyncio.wait never cancels the task: a caller that gives up leaves it going
        self._waiting += 1
        try:
            await asyncio.wait((task,))
        finally:
            self._waiting -= 1
        if task.cancelled():
            raise ConnectionLost("driver closed", channel=channel, address=address)
        exc = task.exception()
        if exc is None:
            return task.result()
        wrapped = self._connect_failed(exc, what, channel, address)
        if wrapped is exc:
            raise exc
        raise wrapped from exc

    async def _attempt(self) -> S:
        """One connect, in its own task: bounded by `connect_timeout_s`; a failure
        (or a cancellation by `close()`) starts the backoff delay."""
        try:
            async with deadline(self.connect_timeout_s):
                s = await self._open_session()
        except BaseException:
            self.backoff.failed()
            raise
        if self.closed:  # closed while connecting
            await self._drop_session(s, True)
            raise ConnectionLost("driver closed")
        self.session = s
        self.backoff.succeeded()
        return s

    def _attempted(self, task: asyncio.Task[S]) -> None:
        if self._connecting is task:
            self._connecting = None
        if not task.cancelled():
            task.exception()  # retrieved: its callers (if any) raise it themselves

    def _gate(self, channel: Channels, address: str | None) -> None:
        if self.closed:
            raise ConnectionLost("driver closed", channel=channel, address=address)
        if not self.backoff.ready():
            raise ConnectionLost(f"{self.endpoint} down; next reconnect attempt in "
                                 f"≤{self.backoff.delay_s:.2f} s (backing off)",
                                 channel=channel, address=address)

    def _connect_failed(self, exc: BaseException, what: str, channel: Channels,
                        address: str | None) -> BaseException:
        if isinstance(exc, DriverError) or not isinstance(exc, Exception):
            return exc
        after = f"; next attempt in {self.backoff.delay_s:.2f} s"
        if isinstance(exc, self._timeout_errors):
            return ControllerTimeout(f"connect to {self.endpoint} timed out during {what}"
                                     f"{after}", channel=channel, address=address)
        if isinstance(exc, self._connect_errors):
            return ConnectionLost(f"cannot connect to {self.endpoint} during {what}: "
                                  f"{exc or type(exc).__name__}{after}",
                                  channel=channel, address=address)
        return exc

    async def lost(self, session: S) -> None:
        """`session` failed under a call: drop it and start the backoff delay
        (the next calls fail fast instead of each trying a controller that
        just stopped answering)."""
        if self.session is session:
            self.session = None
            self.backoff.failed()
        await self._drop_session(session, False)

    async def call(self, op: Callable[[S], Awaitable[T]], what: str,
                   channel: Channels = None, address: str | None = None, *,
                   where: Callable[[], tuple[Channels, str | None]] | None = None) -> T:
        """Run `op` on the session (opened first when due); see the module
        for what a failure does to the link. The errors name `channel` and
        `address`, or what `where()` gives (asked only on a failure)."""
        s = self.session
        if s is None or (self._alive is not None and not self._alive(s)):
            if where is not None:
                channel, address = where()
            s = await self.ready(what, channel, address)
        try:
            return await op(s)
        except (ConnectionLost, ControllerTimeout):
            await self.lost(s)
            raise
        except self._timeout_errors as exc:
            await self.lost(s)
            if where is not None:
                channel, address = where()
            raise ControllerTimeout(f"{what} on {self.endpoint} timed out after "
                                    f"{self.timeout_s} s", channel=channel,
                                    address=address) from exc
        except self._lost_errors as exc:
            await self.lost(s)
            if where is not None:
                channel, address = where()
            raise ConnectionLost(f"{what} on {self.endpoint} lost the link: {exc}",
                                 channel=channel, address=address) from exc

    async def close(self) -> None:
        """Closed for calls until `connect()`; a connect in progress is
        cancelled, the session is torn down."""
        self.closed = True
        await self._cancel_connect()
        s, self.session = self.session, None
        if s is not None:
            await self._drop_session(s, True)

    async def _cancel_connect(self) -> None:
        task, self._connecting = self._connecting, None
        if task is not None:
            task.cancel()
            await asyncio.wait((task,))


class LinkedDriver:
    """What a driver's lifecycle shows of its `Link` (`_link`): `connected`,
    `backoff`, `connect()` and `close()`, the same for every protocol."""

    _link: Link[Any]

    @property
    def connected(self) -> bool:
        """True while the link is believed to be up."""
        return self._link.up

    @property
    def backoff(self) -> Backoff:
        """The reconnect backoff of this driver's link."""
        return self._link.backoff

    async def connect(self) -> None:
        """Open the link now (also after `close()`)."""
        await self._link.connect()

    async def close(self) -> None:
        """Release the link (and a worker thread); calls fail until `connect()`."""
        await self._link.close()


#: extra time the event loop waits for the worker beyond a call's own deadline
WORKER_GRACE_S = 0.25


async def _nothing(session: object, closing: bool) -> None:
    """A worker session is dropped on the worker (see `WorkerLink`)."""


class WorkerLink(Link[S]):
    """A `Link` whose session lives on one `IoThread` (a blocking library).

    `open_sync` opens a session on the worker thread, `run(op)` runs
    `op(session)` there; when `op` fails with one of `drop_on`, the job drops
    the session (`drop_sync`) before the error leaves the thread. After a
    timeout the thread may still be stuck: nothing waits for it, and the next
    `open_sync` drops the stale session first. `close()` drops it on the
    worker and stops the thread (a later `connect()` starts a new one).
    """

    def __init__(self, endpoint: str, backoff: Backoff, timeout_s: float, *, io: IoThread,
                 open_sync: Callable[[], S], drop_sync: Callable[[], None],
                 drop_on: tuple[type[BaseException], ...],
                 connect_errors: tuple[type[BaseException], ...] = (OSError,),
                 timeout_errors: tuple[type[BaseException], ...] = (),
                 lost_errors: tuple[type[BaseException], ...] = ()) -> None:
        self.io = io
        self._wait_s = timeout_s + WORKER_GRACE_S
        self._drop_sync = drop_sync
        self._drop_on = drop_on
        super().__init__(endpoint, backoff, timeout_s,
                         open=lambda: io.call(open_sync, self._wait_s), drop=_nothing,
                         connect_errors=connect_errors, timeout_errors=timeout_errors,
                         lost_errors=lost_errors)

    def _job(self, op: Callable[[S], T], session: S) -> T:
        try:
            return op(session)
        except self._drop_on:
            self._drop_sync()
            raise

    def run(self, op: Callable[[S], T], what: str, channel: Channels = None,
            address: str | None = None) -> Awaitable[T]:
        """`op(session)` on the worker thread, under `Link.call`'s rules."""
        return self.call(
            lambda s: self.io.call(partial(self._job, op, s), self._wait_s),
            what, channel, address)

    async def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        await self._cancel_connect()
        self.session = None
        try:
            await self.io.call(self._drop_sync, self._wait_s)
        except (TimeoutError, DriverError):
            pass
        finally:
            self.io.shutdown()


__all__ = ["Link", "LinkedDriver", "WorkerLink"]
