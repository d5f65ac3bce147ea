"""The tests' harness: the real daemon in-process, its clock stepped or its
condition polled, whatever the machine's load.

- `until(predicate, ...)`: the one poller (sync or async predicate, a generous
  real-time bound; fails early when the daemon's task or process ended);
  `until_output` polls a simulated controller's output register with it.
- `asleep(clock, n, task)`: until the daemon on a `compd.testing.SteppedClock`
  began its n-th sleep (it finished a cycle), or failed with what it raised.
- `pace(clock, goal)`: move the stepped clock to each next deadline as soon as
  the daemon sleeps, until `goal` holds after a cycle.
- `stepped_daemon(cfg, ...)`: the real daemon run on a paced `SteppedClock`
  (its cycles as fast as the machine allows, its requests with the config's
  own timeout), stopped and its pacer ended on the way out.
- `EventLog`, `Notes`: the daemon's logger and sd_notify, kept for the test.
- `memory_daemon(cfg)`: the daemon in lockstep over an in-memory controller.
- `modbus_sims(count)`: simulated Modbus controllers for a fleet.
- `Lockstep`, `Fleetstep`: the daemon (or a fleet) in lockstep with the
  simulated machine and its real controller server on 127.0.0.1.

The lockstep run, each machine period, in this order:

1. the plant advances one period, takes the offset the controller holds and
   publishes its sensors to the server (`SimMachine.tick`);
2. the clock moves one period: the daemon's deadline is due, it runs one
   cycle (reads over the real protocol, steps, writes over the real protocol);
3. the harness waits until the daemon sleeps again (an event, not a timeout).

Nothing waits on wall time, so a loaded machine makes a run slower, never
different: the daemon never falls behind the plant and never misses a probe.

A lost link (the test stops the server) fails the daemon's reads at once;
when the test starts the server again, `reconnect()` makes the driver's
reconnect attempt before the next cycle, as its backoff would in real time.

A "kill -9" (`kill9`) drops the daemon without its shutdown: no final
checkpoint, no shutdown policy, the recorder's uncommitted rows lost; its
sockets and state lock are released as the kernel would. `start()` then makes
a new `Daemon` on the same config and state directory. While no daemon runs
the machine stands still unless the test says otherwise (`idle(periods)`).

Sample ages and the checkpoint's age are judged on the real wall clock (the
servers stamp samples with it), at ``time_scale = 1``: a restart sees a
checkpoint seconds old, however long the test took.

What stays elsewhere, being different: `tests.faults.daemon_rig.DaemonRig`
checks every write against the fault invariants and calls the test's plant
before each read; `tests.faults.daemon_run` runs `compd run` as a process (kill
-9, a second instance, a full disk); `tests.faults.clocked_driver` moves a
`FakeClock` from inside the driver's read; `tests.compd.faces.status_helpers` serves
the operator page; `tests.compd.core.cycle_helpers` feeds the pure cycle (no daemon).
The configs are `tests.configs`.

It lives in tests/ rather than `compd.testing` because it composes the shell
(`compd.runtime`) with `drivers.sim`; `compd.testing` holds the doubles that
only depend on `drivers.base` (its `SteppedClock` is what drives this).
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from compd.runtime.sdnotify import Notifier
from compd.testing import SteppedClock

if TYPE_CHECKING:
    from compd.config.loader import LoadedConfig
    from compd.runtime.daemon import Daemon
    from compd.testing import MemoryDriver
    from drivers.sim.base import SimController
    from drivers.sim.machine import SimMachine
    from drivers.sim.modbus_server import ModbusSimController

__all__ = ["DaemonEnded", "EventLog", "Fleetstep", "Lockstep", "Notes", "Paced", "asleep",
           "memory_daemon", "modbus_sims", "pace", "stepped_daemon", "tail", "until",
           "until_output"]


class DaemonEnded(AssertionError):
    """The daemon returned (or raised) while the harness waited for its cycle."""


async def until(predicate: Callable[..., Any], proc: asyncio.subprocess.Process | None = None,
                log: Path | None = None, what: str = "condition", *, limit_s: float = 120.0,
                task: asyncio.Future[Any] | None = None, every_s: float = 0.005) -> None:
    """Poll `predicate` (sync or async) every `every_s` until it is true. Fail naming
    `what` when `limit_s` real seconds have passed (generous: a loaded machine makes
    a test slower, never red), or at once when the daemon's `task` ended (raising
    what it raised) or its process `proc` exited; the tail of `log` in the message."""
    deadline = time.monotonic() + limit_s
    while True:
        got = predicate()
        if asyncio.iscoroutine(got):
            got = await got
        if got:
            return
        if task is not None and task.done():
            rc = task.result()  # raises what the daemon raised
            raise DaemonEnded(f"{what}: the daemon ended (status {rc}) before it")
        if (proc is not None and proc.returncode is not None) or time.monotonic() > deadline:
            break
        await asyncio.sleep(every_s)
    text = "" if log is None else "; log:\n" + await asyncio.to_thread(tail, log)
    rc = "" if proc is None else f" (daemon rc {proc.returncode})"
    raise AssertionError(f"{what}: not reached within {limit_s:g} s{rc}{text}")


async def healthy_within(ask: Callable[[], int], cycles: Callable[[], int],
                         tries: int = 30) -> int:
    """A health check of a daemon that runs in real time, asked until it answers
    healthy (0), at most `tries` times, waiting for the daemon's next complete cycle
    (`cycles`: its count) between two asks. On a loaded PC one read or write may
    time out and make one instant rightly unhealthy; the check asked once at that
    instant would turn a slow machine into a red test. Returns the last answer."""
    rc = await asyncio.to_thread(ask)
    for _ in range(tries - 1):
        if rc == 0:
            break
        seen = cycles()
        await until(lambda seen=seen: cycles() > seen, what="the next complete cycle")
        rc = await asyncio.to_thread(ask)
    return rc


async def until_output(sim: SimController, key: str, predicate: Callable[[float], Any],
                       proc: asyncio.subprocess.Process | None = None,
                       log: Path | None = None, limit_s: float = 120.0) -> None:
    """`until` the controller's output `key` (offset, heartbeat, status) satisfies
    `predicate`."""
    async def holds() -> bool:
        return bool(predicate((await sim.outputs())[key]))

    await until(holds, proc, log, f"{key} satisfying the condition", limit_s=limit_s,
                every_s=0.01)


def tail(log: Path, chars: int = 4000) -> str:
    """The end of a log file ('' when there is none)."""
    return log.read_text(errors="replace")[-chars:] if log.exists() else ""


async def asleep(clock: SteppedClock, n: int, task: asyncio.Future[Any]) -> None:
    """Until the `n`-th sleep on `clock` has begun (the daemon finished a cycle);
    `DaemonEnded`, with what `task` raised, when the daemon ended first."""
    waiter = asyncio.ensure_future(clock.cycle_done(n))
    done, _ = await asyncio.wait({waiter, task}, return_when=asyncio.FIRST_COMPLETED)
    if waiter in done:
        return
    waiter.cancel()
    await asyncio.gather(waiter, return_exceptions=True)
    rc = task.result()  # raises what the daemon raised
    raise DaemonEnded(f"the daemon ended (status {rc}) during a cycle")


async def pace(clock: SteppedClock, goal: Callable[[], bool] | None = None) -> None:
    """Each time the daemon sleeps on `clock`, move the clock to its next deadline:
    its cycles follow each other as fast as the machine allows, one period apart on
    its clock. With a `goal`, stop once it holds after a cycle: then the clock stays,
    and so does the daemon (a condition on the cycles is met at that cycle, however
    late the test looks). Without one, a task the test cancels."""
    while True:
        await clock.cycle_done(clock.ticks + 1)
        if goal is not None and goal():
            return
        clock.tick()


class Paced:
    """A daemon running on a paced `SteppedClock` (`stepped_daemon`)."""

    def __init__(self, daemon: Daemon, clock: SteppedClock, task: asyncio.Task[int]) -> None:
        self.daemon = daemon
        self.clock = clock
        #: the daemon's `run()`: its exit status, or what it raised
        self.task = task

    async def until(self, predicate: Callable[..., Any], what: str = "condition") -> None:
        """`until` the predicate holds; at once `DaemonEnded` when the daemon ended."""
        await until(predicate, what=what, task=self.task)

    async def stop(self) -> int:
        """SIGTERM: the daemon's shutdown, its cycles still paced; its exit status."""
        self.daemon.request_stop()
        return await self.task


@contextlib.asynccontextmanager
async def stepped_daemon(cfg: LoadedConfig, **daemon_args: Any) -> AsyncIterator[Paced]:
    """The real `Daemon(cfg, **daemon_args)` (sd_notify to nowhere unless a
    `notifier` is given) running on a `SteppedClock` of the config's real period,
    moved to each next deadline as soon as the daemon sleeps (`pace`): cycles are
    counted, never waited out, and each request has the config's own timeout (a
    config at time_scale 1 gives 0.4 s, which a loaded machine meets; the sim's
    default 8 ms it may not). On the way out a daemon the test did not stop is
    stopped (a ramp-to-zero shutdown paced to its end) and the pacer ended:
    nothing is left running."""
    from compd.runtime.daemon import Daemon

    clock = SteppedClock(period_s=cfg.real_period_s)
    daemon_args.setdefault("notifier", Notifier(None))
    daemon = Daemon(cfg, clock=clock, sleep=clock.sleep, **daemon_args)
    pacer = asyncio.create_task(pace(clock), name="stepped-daemon-pace")
    task = asyncio.create_task(daemon.run(), name="stepped-daemon")
    try:
        yield Paced(daemon, clock, task)
    finally:
        if not task.done():
            daemon.request_stop()
            await asyncio.wait({task}, timeout=120.0)
            task.cancel()
        pacer.cancel()
        await asyncio.gather(task, pacer, return_exceptions=True)


class EventLog:
    """Stands in for the daemon's structlog logger: keeps (level, event, fields)."""

    def __init__(self) -> None:
        self.events: list[tuple[str, str, dict[str, Any]]] = []

    def _at(self, level: str) -> Callable[..., None]:
        def log(event: str, **fields: Any) -> None:
            if level != "debug":
                self.events.append((level, event, fields))
        return log

    def __getattr__(self, level: str) -> Callable[..., None]:
        return self._at(level)

    def names(self) -> list[str]:
        return [e for _, e, _ in self.events]


class Notes(Notifier):
    """sd_notify to nowhere, keeping each message it would send (a datagram queue
    holds only 10; `Notifier.sent` counts them)."""

    def __init__(self) -> None:
        super().__init__(None)
        self.messages: list[str] = []

    def notify(self, message: str) -> bool:
        self.messages.append(message)
        return True

    @property
    def is_ready(self) -> bool:
        return any(m.startswith("READY=1") for m in self.messages)


def memory_daemon(cfg: LoadedConfig, *, epoch: float | None = None,
                  **daemon_args: Any) -> tuple[Daemon, SteppedClock, MemoryDriver]:
    """The real daemon in-process over an in-memory controller (bearing and
    ambient at 20 °C; offset, heartbeat and status written), driven by one
    `SteppedClock`: a cycle per `clock.tick()`, awaited with `clock.cycle_done`.
    `epoch`: the wall clock's reading at the stepped clock's 0, for the driver's
    sample stamps and the daemon (None: the daemon's own wall clock)."""
    from compd.runtime.daemon import Daemon
    from compd.testing import MemoryDriver

    clock = SteppedClock(period_s=cfg.period_s)
    stamped: dict[str, Any] = {}
    if epoch is not None:
        start = epoch

        def wall() -> float:
            return start + clock()

        stamped["wall"] = wall
    driver = MemoryDriver({"bearing": 20.0, "ambient": 20.0},
                          ("offset", "heartbeat", "status"), **stamped)
    daemon = Daemon(cfg, driver=driver, notifier=Notifier(None), clock=clock,
                    sleep=clock.sleep, **stamped, **daemon_args)
    return daemon, clock, driver


@contextlib.asynccontextmanager
async def modbus_sims(count: int) -> AsyncIterator[list[ModbusSimController]]:
    """`count` simulated Modbus controllers on free 127.0.0.1 ports, bearing and
    ambient at 20 °C, stopped on exit."""
    from drivers.sim.modbus_server import ModbusSimController

    controllers = [ModbusSimController() for _ in range(count)]
    for c in controllers:
        await c.start()
        await c.publish({"bearing": 20.0, "ambient": 20.0})
    try:
        yield controllers
    finally:
        for c in controllers:
            await c.stop()


class Lockstep:
    """One simulated machine and the daemon(s) compensating it, period by period."""

    def __init__(self, machine: SimMachine, config_path: Path) -> None:
        self.machine = machine
        self.config_path = config_path
        self.clock = SteppedClock(period_s=machine.period_s)
        self.daemon: Daemon | None = None
        #: the events each daemon started logged (level, name, fields), in start order
        self.logs: list[EventLog] = []
        #: the exit status of each daemon stopped with `stop()` (a kill leaves None)
        self.exits: list[int | None] = []
        self._task: asyncio.Task[int] | None = None

    @property
    def running(self) -> bool:
        return self._task is not None and not self._task.done()

    async def _asleep(self, n: int) -> None:
        """Until the daemon began its n-th sleep (it finished a cycle), or it ended."""
        assert self._task is not None
        await asleep(self.clock, n, self._task)

    async def start(self) -> Daemon:
        """A new daemon on the config file (read now) and its state directory;
        returns after its first cycle that heard the controller (READY=1), the
        machine standing still (its values published again) until then."""
        if self.running:
            raise RuntimeError("a daemon is running: kill9() or stop() it first")
        if not self.machine._primed:
            await self.machine.prime()
        from compd.config.loader import load_config
        from compd.runtime.daemon import Daemon

        notes = Notes()
        daemon = Daemon(load_config(self.config_path), clock=self.clock,
                        sleep=self.clock.sleep, notifier=notes)
        log = EventLog()
        daemon.journal.log = log
        self.logs.append(log)
        self.daemon = daemon
        n = self.clock.sleeps + 1
        self._task = asyncio.create_task(daemon.run(), name="lockstep-daemon")
        await self._asleep(n)
        while not notes.is_ready:
            await self.machine.controller.publish(self.machine.plant.sensors())
            n = self.clock.sleeps + 1
            self.clock.tick()
            await self._asleep(n)
        return daemon

    async def step(self, periods: int = 1) -> None:
        """`periods` machine periods, each: plant tick, then one daemon cycle."""
        for _ in range(periods):
            await self.machine.tick()
            if self.running:
                n = self.clock.sleeps + 1
                self.clock.tick()
                await self._asleep(n)
            else:
                self.clock.tick()

    async def run_until(self, t_s: float) -> None:
        """Step until the machine's time reaches `t_s` (machine seconds)."""
        while self.machine.time_s < t_s - 1e-6:
            await self.step()

    async def idle(self, periods: int) -> None:
        """The machine runs `periods` periods with no daemon (it must not run)."""
        if self.running:
            raise RuntimeError("idle() is for the time no daemon runs")
        await self.step(periods)

    async def reconnect(self) -> None:
        """The controller is back: the driver's reconnect attempt, made now, between
        two cycles (its backoff delay runs on real time, which lockstep never waits
        on: without this the number of cycles until it reconnects would depend on
        how fast the machine is)."""
        daemon = self.daemon
        if daemon is None or daemon.running.driver is None or not self.running:
            raise RuntimeError("no daemon runs")
        await daemon.running.driver.connect()

    async def kill9(self) -> None:
        """Drop the daemon as SIGKILL would: between two cycles, no shutdown
        policy, no final checkpoint, the recorder's buffered rows lost."""
        task, daemon = self._task, self.daemon
        if task is None or daemon is None:
            return
        recorder = daemon.recorder.recorder
        if recorder is not None:
            recorder._buffer.clear()  # uncommitted rows die with the process
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        self._task = None
        self.exits.append(None)

    async def stop(self) -> int:
        """SIGTERM: the daemon's shutdown (its policy, its cycles stepped in
        lockstep, the final checkpoint); returns its exit status."""
        task, daemon = self._task, self.daemon
        if task is None or daemon is None:
            raise RuntimeError("no daemon runs")
        daemon.request_stop()
        while True:
            n = self.clock.sleeps + 1
            waiter = asyncio.ensure_future(self.clock.cycle_done(n))
            done, _ = await asyncio.wait({waiter, task}, return_when=asyncio.FIRST_COMPLETED)
            if task in done:
                waiter.cancel()
                await asyncio.gather(waiter, return_exceptions=True)
                break
            # a ramp-to-zero shutdown cycles on: the machine goes on with it
            await self.machine.tick()
            self.clock.tick()
        self._task = None
        rc = task.result()
        self.exits.append(rc)
        return rc

    async def close(self) -> None:
        """After a failure: drop a daemon still running (as `kill9`)."""
        if self.running:
            await self.kill9()


class Fleetstep:
    """Several daemons on one `SteppedClock` (the machines of `compd run DIR`,
    `compd.runtime.fleet.Fleet(..., clock=clock, sleep=clock.sleep)`), stepped
    together: each `step` moves the clock one period and returns once every
    daemon that move woke has run its cycle and sleeps again (an event, never
    a timeout). Servers between them are the test's (it stops, starts them)."""

    def __init__(self, clock: SteppedClock, task: asyncio.Future[Any]) -> None:
        self.clock = clock
        #: the fleet's `run()`: its end (or error) ends any wait
        self.task = task

    async def until_asleep(self, n: int) -> None:
        """Until `n` sleeps have begun on the clock (since it was made)."""
        await asleep(self.clock, n, self.task)

    async def step(self, periods: int = 1) -> None:
        for _ in range(periods):
            n = self.clock.sleeps + self.clock.due()
            self.clock.tick()
            await self.until_asleep(n)
