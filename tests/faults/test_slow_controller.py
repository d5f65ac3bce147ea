"""Fault "slow controller" at the driver level, for every TCP protocol.

Each driver talks to its simulated controller through `FaultProxy` on
127.0.0.1, which adds latency, blackholes, resets (RST) or cuts a connection
after k bytes. What must hold:

- a request fails with `ControllerTimeout` (or another `DriverError`) within
  its timeout, timeout_s = 0.5·Ts: bounded here by `asyncio.wait_for(timeout
  + margin)`, never a wall-clock assertion tighter than that; while the
  driver backs off, calls fail fast with `ConnectionLost` and put nothing on
  the wire (the proxy sees no new connection and no new request);
- a write is never sent twice by the transport (counted as request frames at
  the proxy and at the server);
- a cycle whose call fails is skipped and counted, never queued: one attempt
  per period on absolute deadlines, no burst after the link returns, and the
  server sees exactly one write per completed cycle;
- after the link returns, the same driver object reads and writes again
  within 10 s + 2·Ts;
- after `close()`, the asyncio task count and this process's open file
  descriptors are back to what they were before the driver was created.

The reconnect backoff of the link tests runs on a `compd.testing.FakeClock`
(`Rig.clock`): a call inside the backoff delay fails fast however slow the
machine, and the test moves the clock past the delay instead of sleeping it
out. The requests' timeouts are real seconds, as on a shop floor.

OPC UA drivers get ``connect_timeout_s = timeout_s`` here (a reconnect runs
in the link's own task, started by `read`/`write`; each of its requests is
bounded by timeout_s anyway, the whole handshake by connect_timeout_s, by
default max(2·timeout, 1 s); see
`test_opcua_reconnect_outlives_a_read_that_gave_up`). The first connect of
each test is not the subject: it may retry (`connect_up`), as on a loaded
machine an OPC UA handshake can exceed 0.2 s.
"""

from __future__ import annotations

import asyncio
import math
import os
from collections.abc import AsyncIterator, Awaitable, Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, TypeVar
from urllib.parse import urlsplit

import pytest
import pytest_asyncio

from compd.testing import FakeClock
from drivers.backoff import Backoff
from drivers.base import Driver
from drivers.errors import ConnectionLost, ControllerTimeout, DriverError
from drivers.factory import open_driver
from drivers.sim.base import SimController
from drivers.sim.registry import make_sim_controller
from tests.faults.frames import FRAME_LENGTH, IS_WRITE
from tests.faults.proxy import FaultProxy

T = TypeVar("T")

pytestmark = pytest.mark.asyncio(loop_scope="module")

PROTOCOLS = ("opcua", "modbus", "s7")
#: sample period and request timeout (timeout = 0.5·Ts, the most a request may take)
TS_S = 0.4
TIMEOUT_S = 0.5 * TS_S
#: scheduling slack on a loaded 2-core machine: the bound is timeout + this
MARGIN_S = 0.5
#: the link is back: compensation must resume within this
RECOVER_WITHIN_S = 10.0 + 2 * TS_S
#: a latency well above the timeout
LATENCY_S = 3 * TIMEOUT_S
#: the backoff after a failure is long enough that the next call is surely inside it
BACKOFF = (0.5, 2.0)
#: bound for resources to drain after close (sockets and tasks unwind)
DRAIN_S = 5.0

READ_NAMES = ["bearing", "motor", "ambient", "spindle_rpm", "offset"]
WRITES: dict[str, float] = {"offset": 12.5, "heartbeat": 7.0, "status": 1.0}


@dataclass
class Rig:
    protocol: str
    sim: SimController
    proxy: FaultProxy
    #: the backoff's clock for `driver(fake_backoff=True)`: moved by the test
    clock: FakeClock = field(default_factory=FakeClock)

    @property
    def endpoint(self) -> str:
        """The sim's endpoint with the proxy's port."""
        return urlsplit(self.sim.endpoint)._replace(
            netloc=f"{self.proxy.host}:{self.proxy.port}").geturl()

    def driver(self, timeout_s: float = TIMEOUT_S, backoff: tuple[float, float] = BACKOFF,
               opcua_connect_timeout_s: float | None = None,
               fake_backoff: bool = False) -> Driver:
        """`opcua_connect_timeout_s`: None = timeout_s (OPC UA only);
        `fake_backoff`: the backoff delay on `clock` (real seconds otherwise)."""
        options: dict[str, Any] = {}
        if self.protocol == "opcua":
            options["connect_timeout_s"] = opcua_connect_timeout_s or timeout_s
        delays = Backoff(*backoff, clock=self.clock) if fake_backoff else Backoff(*backoff)
        return open_driver(self.protocol, self.endpoint, self.sim.channels,
                           self.sim.outputs_map, timeout_s=timeout_s, backoff=delays,
                           **options)

    def writes_sent(self) -> int:
        """Write requests the proxy received from the client."""
        return self.proxy.count_frames(IS_WRITE[self.protocol])

    def writes_served(self) -> int:
        """Write requests the simulated controller received."""
        sim: Any = self.sim
        if self.protocol == "modbus":
            return sum(1 for r in sim.requests if r.function_code in (6, 16))
        if self.protocol == "opcua":
            return int(sim.write_requests)
        return int(sim.request_counts().get(0x05, 0))

    def traffic(self) -> tuple[int, int]:
        """(connections accepted, request frames received): unchanged = nothing sent."""
        return self.proxy.connections_accepted, len(self.proxy.frames_received)


@pytest_asyncio.fixture(scope="module", loop_scope="module", params=PROTOCOLS)
async def sim(request: pytest.FixtureRequest) -> AsyncIterator[SimController]:
    """One simulated controller per protocol for the module (an OPC UA server
    takes seconds to build its address space); each test gets its own proxy."""
    controller = make_sim_controller(request.param)
    await controller.start()
    try:
        yield controller
    finally:
        await controller.stop()


@pytest_asyncio.fixture(loop_scope="module")
async def rig(sim: SimController) -> AsyncIterator[Rig]:
    parts = urlsplit(sim.endpoint)
    if parts.hostname is None or parts.port is None:
        raise RuntimeError(f"sim endpoint without host/port: {sim.endpoint}")
    proxy = FaultProxy(parts.hostname, parts.port, frame_length=FRAME_LENGTH[sim.protocol])
    await proxy.start()
    try:
        yield Rig(sim.protocol, sim, proxy)
    finally:
        await proxy.stop()


async def finish(rig: Rig, driver: Driver) -> None:
    """Close the driver, then let the proxy deliver what it still holds and
    close its side (so the test leaves no proxy task behind)."""
    await bounded(driver.close())
    if not await rig.proxy.wait_idle(LATENCY_S + DRAIN_S):
        pytest.fail("the proxy still holds a connection after the driver closed")


async def bounded(call: Awaitable[T], timeout_s: float = TIMEOUT_S) -> T:
    """The call, which must finish (return or raise) within timeout + margin."""
    try:
        return await asyncio.wait_for(call, timeout_s + MARGIN_S)
    except ControllerTimeout:
        raise  # the driver's own timeout (also a TimeoutError), not a hang
    except TimeoutError:
        pytest.fail(f"a driver call hung past {timeout_s} s + {MARGIN_S} s margin")


async def connect_up(driver: Driver, timeout_s: float = TIMEOUT_S,
                     clock: FakeClock | None = None) -> None:
    """The first connect (a few tries: not what these tests are about). With the
    driver's backoff on `clock`, each try moves it past the backoff's cap too."""
    for _ in range(4):
        try:
            await bounded(driver.connect(), timeout_s)
            return
        except DriverError:
            await asyncio.sleep(BACKOFF[1])
            if clock is not None:
                clock.advance(BACKOFF[1])
    await bounded(driver.connect(), timeout_s)


async def read_and_write(driver: Driver) -> None:
    await bounded(driver.read(READ_NAMES))
    await bounded(driver.write(WRITES))


async def up(driver: Driver, clock: FakeClock) -> None:
    """Connected, and one read and write through (`connect_up`, then as after an
    outage): the healthy exchange before a fault is not what these tests are
    about, and on a loaded machine one of its requests may miss timeout_s."""
    await connect_up(driver, clock=clock)
    await until_recovered(driver, clock=clock)


async def on_healthy_link(rig: Rig, driver: Driver, call: Callable[[], Awaitable[T]]) -> T:
    """`call()` on a link without a fault, bounded; one that missed timeout_s on a
    loaded machine is made again once the link is back (at most 5 tries)."""
    for _ in range(5):
        try:
            return await bounded(call())
        except ControllerTimeout:
            await until_recovered(driver, clock=rig.clock)
    pytest.fail("no call answered within timeout_s on a link without a fault in 5 tries")


async def until_recovered(driver: Driver, period_s: float = TS_S,
                          clock: FakeClock | None = None) -> int:
    """Read and write as the daemon would, once per period, until both work;
    returns the failed attempts. Fails the test past 10 s + 2·Ts. With the
    driver's backoff on `clock`: the backoff delay has passed when the link
    returns (the clock moves past its cap), and each period moves it too."""
    loop = asyncio.get_running_loop()
    start = loop.time()
    failures = 0
    if clock is not None:
        clock.advance(BACKOFF[1])
    for k in range(math.ceil(RECOVER_WITHIN_S / period_s) + 1):
        try:
            await read_and_write(driver)
            return failures
        except DriverError:
            failures += 1
        await asyncio.sleep(max(0.0, start + (k + 1) * period_s - loop.time()))
        if clock is not None:
            clock.advance(period_s)
    pytest.fail(f"no complete read+write within {RECOVER_WITHIN_S} s after the link returned")


def open_fds() -> int:
    return len(os.listdir("/proc/self/fd"))


async def settle(measure: Callable[[], int], baseline: int) -> int:
    """Poll until `measure()` is back to `baseline` (or DRAIN_S passed); the last value."""
    value = measure()
    for _ in range(int(DRAIN_S / 0.05)):
        value = measure()
        if value <= baseline:
            break
        await asyncio.sleep(0.05)
    return value


# -- unresponsive link: latency and blackhole ------------------------------------------

def _make_unresponsive(rig: Rig, mode: str) -> None:
    if mode == "latency":
        rig.proxy.latency(LATENCY_S, LATENCY_S)
    else:
        rig.proxy.blackhole()


@pytest.mark.parametrize("mode", ["latency", "blackhole"])
async def test_unresponsive_link(rig: Rig, mode: str) -> None:
    """Timeouts within timeout_s, fail fast while backing off, the timed-out
    write sent once, the same driver back after the link returns."""
    driver = rig.driver(fake_backoff=True)
    try:
        await up(driver, rig.clock)
        sent, served = rig.writes_sent(), rig.writes_served()
        _make_unresponsive(rig, mode)

        with pytest.raises(ControllerTimeout):
            await bounded(driver.write(WRITES))
        # inside the backoff delay: fail fast, nothing on the wire
        before = rig.traffic()
        with pytest.raises(ConnectionLost):
            await bounded(driver.read(READ_NAMES))
        with pytest.raises(ConnectionLost):
            await bounded(driver.write(WRITES))
        assert rig.traffic() == before, "a call inside the backoff delay touched the network"
        # after the delay: one reconnect attempt, again bounded by the timeout
        rig.clock.advance(BACKOFF[0])
        with pytest.raises(ControllerTimeout):
            await bounded(driver.read(READ_NAMES))
        with pytest.raises(ConnectionLost):
            await bounded(driver.read(READ_NAMES))

        # no transport-level retry: give a library retry, and the late delivery
        # of what the proxy holds, time to happen
        await asyncio.sleep(LATENCY_S + 2 * TIMEOUT_S)
        assert rig.writes_sent() - sent == 1, "the write left the client more than once"
        assert rig.writes_served() - served <= 1, "the server saw the write more than once"
        if mode == "latency":  # the held request arrives late, once
            assert rig.writes_served() - served == 1

        rig.proxy.pass_through()
        await until_recovered(driver, clock=rig.clock)
        assert (await rig.sim.outputs())["offset"] == pytest.approx(WRITES["offset"])
    finally:
        await finish(rig, driver)


@pytest.mark.parametrize("mode", ["reset", "cut"])
async def test_broken_link(rig: Rig, mode: str) -> None:
    """A reset, or a connection cut halfway through a read's response: a
    driver error (not a hang), on new connections too; then back."""
    driver = rig.driver(fake_backoff=True)
    try:
        await up(driver, rig.clock)
        await on_healthy_link(rig, driver, lambda: driver.write({**WRITES, "offset": 0.0}))

        async def one_read() -> int:
            down = rig.proxy.bytes_forwarded["down"]
            await driver.read(READ_NAMES)
            return rig.proxy.bytes_forwarded["down"] - down

        response_bytes = await on_healthy_link(rig, driver, one_read)
        if mode == "reset":
            rig.proxy.reset()
        else:
            rig.proxy.cut_after(response_bytes // 2, "down")
            with pytest.raises(DriverError):
                await bounded(driver.read(READ_NAMES))
            rig.proxy.cut_after(0, "down")
        with pytest.raises(DriverError):
            await bounded(driver.read(READ_NAMES))
        rig.clock.advance(BACKOFF[0])
        with pytest.raises(DriverError):  # the reconnect meets the same fault
            await read_and_write(driver)
        rig.proxy.pass_through()
        await until_recovered(driver, clock=rig.clock)
        assert (await rig.sim.outputs())["offset"] == pytest.approx(WRITES["offset"])
    finally:
        await finish(rig, driver)


# -- the cycle loop: skipped and counted, never queued ---------------------------------

@dataclass
class LoopStats:
    attempts: int = 0
    complete: int = 0
    failed: int = 0
    #: deadlines passed while a call ran (an overrun): skipped, never run late
    overrun_skips: int = 0
    #: per period: "ok", "failed" or "skipped"
    outcomes: list[str] = field(default_factory=list)


async def cycle_loop(driver: Driver, periods: int, period_s: float,
                     at_period: Mapping[int, Callable[[], None]],
                     done: Callable[[LoopStats], bool] | None = None) -> LoopStats:
    """The daemon's shape: one read+write per period on absolute deadlines; a
    failed cycle is counted, a missed deadline is skipped, nothing is queued.
    `at_period[k]` runs when period k begins (also when k itself was skipped).
    Ends after `periods` periods, or sooner once `done(stats)` is true."""
    loop = asyncio.get_running_loop()
    stats = LoopStats()
    hooks = sorted(at_period.items())
    deadline = loop.time()
    while len(stats.outcomes) < periods and not (done is not None and done(stats)):
        k = len(stats.outcomes)
        while hooks and hooks[0][0] <= k:
            hooks.pop(0)[1]()
        stats.attempts += 1
        try:
            await asyncio.wait_for(driver.read(READ_NAMES), period_s)
            await asyncio.wait_for(driver.write({**WRITES, "heartbeat": float(k)}), period_s)
            stats.complete += 1
            stats.outcomes.append("ok")
        except (DriverError, TimeoutError):
            stats.failed += 1
            stats.outcomes.append("failed")
        deadline += period_s
        now = loop.time()
        if now > deadline:
            missed = min(math.floor((now - deadline) / period_s) + 1,
                         periods - len(stats.outcomes))
            deadline += missed * period_s
            stats.overrun_skips += missed
            stats.outcomes += ["skipped"] * missed
        await asyncio.sleep(max(0.0, deadline - loop.time()))
    return stats


async def test_failed_cycles_are_skipped_and_counted_never_queued(rig: Rig) -> None:
    period_s, timeout_s = 0.2, 0.1
    outage = range(5, 10)
    # after the outage: until a cycle completes again, bounded only generously
    # (30 s: the backoff's retry and a loaded machine's late answers take their time)
    periods = outage.stop + 150

    def back(stats: LoopStats) -> bool:
        return len(stats.outcomes) >= outage.stop + 5 and "ok" in stats.outcomes[outage.stop:]

    driver = rig.driver(timeout_s=timeout_s, backoff=(0.1, 0.4),
                        opcua_connect_timeout_s=period_s)
    try:
        await connect_up(driver, timeout_s)
        served = rig.writes_served()
        stats = await cycle_loop(driver, periods, period_s,
                                 {outage.start: rig.proxy.blackhole,
                                  outage.stop: rig.proxy.pass_through}, done=back)
        # one attempt per period at most; an overrun's deadlines are skipped, not run late
        assert stats.attempts + stats.overrun_skips == len(stats.outcomes)
        assert stats.complete + stats.failed == stats.attempts
        assert all(stats.outcomes[k] != "ok" for k in outage), stats.outcomes
        assert stats.failed >= 1
        assert "ok" in stats.outcomes[outage.stop:], f"not back after the outage: {stats}"
        # never queued: exactly one write reached the controller per complete cycle,
        # and the last one written is the last complete cycle's
        assert rig.writes_served() - served == stats.complete
        assert rig.writes_sent() <= stats.attempts
        last_ok = max(k for k, o in enumerate(stats.outcomes) if o == "ok")
        assert (await rig.sim.outputs())["heartbeat"] == last_ok
    finally:
        await finish(rig, driver)


# -- recovery and resources ------------------------------------------------------------

async def test_tasks_and_fds_back_to_baseline_after_close(rig: Rig) -> None:
    """Through every fault and back, then close(): the asyncio task count and
    the open file descriptors return to what they were before the driver (the
    sim and the proxy were already running then)."""
    tasks_before = len(asyncio.all_tasks())
    fds_before = open_fds()
    driver = rig.driver(backoff=(0.1, 0.2), fake_backoff=True)
    try:
        await up(driver, rig.clock)
        faults: list[Callable[[], None]] = [
            lambda: rig.proxy.latency(LATENCY_S), rig.proxy.blackhole, rig.proxy.reset,
            lambda: rig.proxy.cut_after(10, "down")]
        for fault in faults:
            fault()
            with pytest.raises(DriverError):
                await read_and_write(driver)
            rig.proxy.pass_through()
            await until_recovered(driver, clock=rig.clock)
    finally:
        await finish(rig, driver)
    tasks_after = await settle(lambda: len(asyncio.all_tasks()), tasks_before)
    fds_after = await settle(open_fds, fds_before)
    # at most the baseline: a socket of an earlier test may close meanwhile
    assert tasks_after <= tasks_before, "asyncio tasks left after close()"
    assert fds_after <= fds_before, "file descriptors left open after close()"


@pytest.mark.parametrize("sim", ["opcua"], indirect=True)
async def test_opcua_reconnect_outlives_a_read_that_gave_up(rig: Rig) -> None:
    """An OPC UA reconnect takes several round trips. Under a latency each
    request survives (round trip < timeout) but the handshake does not fit the
    daemon's own deadline on the read, max(Ts, 2·timeout): the read gives up,
    the handshake goes on (`drivers.link.Link`: the connect is the link's own
    task), and a later read takes its session. One new connection, never a
    handshake started again on every read (which kept the link down for good)."""
    # Real-time margins a loaded PC keeps: a round trip of half the request timeout
    # (0.5 s of slack per request, where 0.2·timeout = 40 ms was once too little),
    # a handshake of several round trips (> 2 s) past the read's deadline, and a
    # connect timeout far above both: the test is about the connect outliving the
    # read that started it, not about the connect's time limit.
    timeout_s = 1.0
    one_way_s = 0.25 * timeout_s
    connect_s = 30.0
    deadline_s = max(TS_S, 2 * timeout_s)  # as cycle_io sets it
    driver = rig.driver(timeout_s=timeout_s, opcua_connect_timeout_s=connect_s,
                        fake_backoff=True)
    try:
        await connect_up(driver, connect_s, rig.clock)
        rig.proxy.reset()
        with pytest.raises(DriverError):
            await bounded(driver.read(READ_NAMES), timeout_s)
        rig.proxy.latency(one_way_s, one_way_s)
        backoff: Backoff = driver.backoff  # type: ignore[attr-defined]
        assert not backoff.ready()
        rig.clock.advance(backoff.delay_s)  # a reconnect attempt is due
        assert backoff.ready()
        connections = rig.proxy.connections_accepted
        with pytest.raises(TimeoutError):  # the daemon's deadline
            await asyncio.wait_for(driver.read(READ_NAMES), deadline_s)
        # the connect goes on; a read meanwhile fails fast, putting nothing new on the wire
        with pytest.raises(ConnectionLost, match="in progress"):
            await bounded(driver.read(READ_NAMES), timeout_s)
        await bounded(driver.connect(), connect_s)  # the same handshake, not a new one
        await bounded(driver.read(READ_NAMES), 2 * timeout_s)
        await bounded(driver.write(WRITES), 2 * timeout_s)
        assert rig.proxy.connections_accepted == connections + 1, \
            "the handshake a read gave up on was started again"
        rig.proxy.pass_through()
    finally:
        await finish(rig, driver)
