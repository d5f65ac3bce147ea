"""Each Modbus request's deadline, kept by one timer per link (`RequestWatch`).

pymodbus 3.16.1 bounds every request with `asyncio.wait_for`: a timer and two
futures per request, three requests a cycle for each machine of a fleet. The
Modbus driver instead takes pymodbus's own request timeout away once the
client is connected (`untimed`: the connect itself stays bounded by it) and
gives each request to a `RequestWatch`:

- `begin` stamps the request's deadline (now + `timeout_s`) and arms the
  timer only when none is armed;
- when the timer fires, a request still in flight whose own deadline has
  passed is failed with `TimeoutError`, set on pymodbus's response future:
  pymodbus handles it as its own timeout (``ModbusIOException``, which the
  driver reports as `ControllerTimeout`); a request whose deadline is later
  (it began after the timer was armed) re-arms the timer for it; with
  nothing in flight the timer stays unarmed until the next `begin`.

So every request still ends at its own deadline, never later, and a cycle's
requests, all done within milliseconds, arm one timer between them.
"""

from __future__ import annotations

import asyncio
import math

from pymodbus.client import AsyncModbusTcpClient

__all__ = ["RequestWatch", "response_future", "untimed"]


def response_future(client: AsyncModbusTcpClient) -> asyncio.Future[object] | None:
    """pymodbus's future for the request in flight (its transaction manager's);
    None where this pymodbus has none."""
    future = getattr(getattr(client, "ctx", None), "response_future", None)
    return future if isinstance(future, asyncio.Future) else None


def untimed(client: AsyncModbusTcpClient) -> bool:
    """Take pymodbus's own timeout off the client's requests, when a
    `RequestWatch` can end them instead (pymodbus keeps the request's future
    where `response_future` finds it); False leaves the client as it was."""
    params: object = getattr(getattr(client, "ctx", None), "comm_params", None)
    if response_future(client) is None or not hasattr(params, "timeout_connect"):
        return False
    params.timeout_connect = None  # wait_for(future, None): no timer, no waiter
    return True


class RequestWatch:
    """The deadline of each request on one link, on one timer (see the module)."""

    __slots__ = ("_client", "_due", "_handle", "armed", "timeout_s")

    def __init__(self, timeout_s: float) -> None:
        self.timeout_s = timeout_s
        #: the client whose request is in flight (None: none)
        self._client: AsyncModbusTcpClient | None = None
        #: the deadline of the request in flight (loop time)
        self._due = math.inf
        self._handle: asyncio.TimerHandle | None = None
        #: timers armed so far (a test counts them)
        self.armed = 0

    def begin(self, client: AsyncModbusTcpClient) -> None:
        """A request on `client` starts now."""
        loop = asyncio.get_running_loop()
        self._client = client
        self._due = loop.time() + self.timeout_s
        if self._handle is None:
            self._arm(loop)

    def end(self) -> None:
        """The request in flight is over (answered, failed or cancelled)."""
        self._client = None

    def close(self) -> None:
        """No request any more: the timer is cancelled."""
        self._client = None
        if self._handle is not None:
            self._handle.cancel()
            self._handle = None

    def _arm(self, loop: asyncio.AbstractEventLoop) -> None:
        self.armed += 1
        self._handle = loop.call_at(self._due, self._fire, loop)

    def _fire(self, loop: asyncio.AbstractEventLoop) -> None:
        self._handle = None
        client = self._client
        if client is None:
            return  # nothing in flight: armed again by the next request
        if loop.time() < self._due:
            self._arm(loop)  # a request that began after the timer was armed
            return
        future = response_future(client)
        if future is not None and not future.done():
            future.set_exception(TimeoutError())
