"""The lockstep harness: the real daemon in-process, the simulated machine,
and the real simulated controller server on 127.0.0.1 between them, all
stepped by one `compd.testing.SteppedClock`.

Each machine period, in this order:

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

It lives in tests/ rather than `compd.testing` because it composes the shell
(`compd.runtime`) with `drivers.sim`; `compd.testing` holds the doubles that
only depend on `drivers.base` (its `SteppedClock` is what drives this).
"""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

from compd.config.loader import load_config
from compd.offline.demo import daemon_config
from compd.runtime.daemon import Daemon
from compd.runtime.sdnotify import Notifier
from compd.testing import SteppedClock
from drivers.sim.base import SimController
from drivers.sim.machine import SimMachine
from models import tomltext
from tests.faults.daemon_rig import EventLog

__all__ = ["Fleetstep", "Lockstep", "lockstep_config"]

#: real seconds the driver may wait for one request and for the connection: a
#: loaded test machine answers late, never "not at all" (a lockstep run does not
#: depend on them unless the server is really gone)
REQUEST_TIMEOUT_S = 10.0
CONNECT_TIMEOUT_S = 30.0


def lockstep_config(sim: SimController, work: Path, *, model: str, period_s: float,
                    **kwargs: Any) -> dict[str, Any]:
    """`compd.offline.demo.daemon_config` for a lockstep run: time_scale 1 (the
    stepped clock counts machine seconds) and generous real-time I/O limits."""
    doc = daemon_config(sim, model=model, period_s=period_s, time_scale=1.0,
                        state_dir=work / "state", **kwargs)
    doc["controller"]["timeout_s"] = min(REQUEST_TIMEOUT_S, 0.5 * period_s)
    doc["controller"]["connect_timeout_s"] = CONNECT_TIMEOUT_S
    return doc


def write_config(doc: dict[str, Any], path: Path) -> Path:
    path.write_text(tomltext.dumps(doc), encoding="utf-8")
    return path


class _Notes(Notifier):
    """sd_notify to nowhere, remembering READY=1."""

    def __init__(self) -> None:
        super().__init__(None)
        self.is_ready = False

    def ready(self) -> None:
        self.is_ready = True


class DaemonEnded(AssertionError):
    """The daemon returned (or raised) while the harness waited for its cycle."""


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
        waiter = asyncio.ensure_future(self.clock.cycle_done(n))
        done, _ = await asyncio.wait({waiter, self._task},
                                     return_when=asyncio.FIRST_COMPLETED)
        if waiter in done:
            return
        waiter.cancel()
        await asyncio.gather(waiter, return_exceptions=True)
        rc = self._task.result()  # raises what the daemon raised
        raise DaemonEnded(f"the daemon ended (status {rc}) during a cycle")

    async def start(self) -> Daemon:
        """A new daemon on the config file (read now) and its state directory;
        returns after its first cycle that heard the controller (READY=1), the
        machine standing still (its values published again) until then."""
        if self.running:
            raise RuntimeError("a daemon is running: kill9() or stop() it first")
        if not self.machine._primed:
            await self.machine.prime()
        notes = _Notes()
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
        waiter = asyncio.ensure_future(self.clock.cycle_done(n))
        done, _ = await asyncio.wait({waiter, self.task}, return_when=asyncio.FIRST_COMPLETED)
        if waiter in done:
            return
        waiter.cancel()
        await asyncio.gather(waiter, return_exceptions=True)
        rc = self.task.result()  # raises what the fleet raised
        raise DaemonEnded(f"the fleet ended (status {rc}) during a cycle")

    async def step(self, periods: int = 1) -> None:
        for _ in range(periods):
            n = self.clock.sleeps + self.clock.due()
            self.clock.tick()
            await self.until_asleep(n)
