"""The loop: one cycle per deadline, its tick fed to the sinks, the shutdown policy.

Scheduling (`compd.core.schedule`): absolute deadlines on the injected
monotonic clock, one every period / time_scale real seconds. A cycle that
ends past its next deadline is an overrun: counted, logged, and the schedule
skips to the next deadline in the future (never a burst of catch-up cycles).

Between two cycles (never during a shutdown ramp) `between` runs: the daemon
swaps a reloaded config in there (`compd.runtime.reloading`). Each cycle
(`one_cycle`): `compd.runtime.cycle_io.CycleIO.run` (read, plan, write,
commit), then every sink is fed the tick (the committed row), none of which
may stop the cycle; its time goes to ``compd_cycle_seconds``; then the
checkpoint (last, outside that time: written and fsynced on the process's disk
thread while this machine's task awaits it, `compd.runtime.diskwriter`); then, when one is due, the
process's full garbage collection (`compd.runtime.gcpolicy`), in the slack
before the next deadline.

A stop request (`stop_requested`): the current cycle finishes, then the
shutdown policy: "hold" ends the loop, "ramp_to_zero" keeps cycling the ramp
until the offset is 0 (or its budget of cycles is spent, or a second stop
request ends it). A cycle that raises even as a failed read is broken
(``cycle_broken``): the shutdown policy is tried (the ramp needs no input and
no model), and the loop ends with EX_SOFTWARE. A checkpoint is written at
the end whichever way the loop ends.
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from typing import TYPE_CHECKING

from compd.core.schedule import Schedule, shutdown_ramp_cycles
from compd.runtime.clock import pause
from compd.sysexits import EX_SOFTWARE

if TYPE_CHECKING:
    from compd.core.cycle import Cycle
    from compd.core.plan import Row
    from compd.faces.telemetry import Metrics
    from compd.runtime.clock import Clock, Instant
    from compd.runtime.cycle_io import CycleIO
    from compd.runtime.gcpolicy import GcPolicy
    from compd.runtime.journal import Journal
    from compd.runtime.sinks.base import CycleSink
    from compd.runtime.sinks.checkpoint import CheckpointSink

__all__ = ["CycleLoop"]


class CycleLoop:
    def __init__(self, io: CycleIO, *, sinks: list[CycleSink], checkpoint: CheckpointSink,
                 journal: Journal, metrics: Metrics, clock: Clock, once: bool = False,
                 between: Callable[[], Awaitable[None]] | None = None,
                 reloads: Callable[[], int] = lambda: 0,
                 gc_policy: GcPolicy | None = None) -> None:
        self.io = io
        self.sinks = sinks
        self.checkpoint = checkpoint
        self.journal = journal
        self.metrics = metrics
        self.clock = clock
        self.once = once
        self.between = between
        self.reloads = reloads
        #: full garbage collections run here, after a cycle, when due (`gcpolicy`)
        self.gc_policy = gc_policy
        self.stop_requested = asyncio.Event()
        #: the signal that asked us to stop (None: a caller's request)
        self.stop_signal: str | None = None
        self.cycles = 0
        self.overruns = 0
        self.last_result: Row | None = None
        self._checkpoint_due = False

    async def one_cycle(self, at: Instant) -> Row:
        tick = await self.io.run(at)
        self.cycles += 1
        self.last_result = tick.row
        for sink in self.sinks:  # none of them may stop the cycle (the offset is written)
            self.journal.guard(sink.stage, sink.feed, tick)
        self._checkpoint_due = self.checkpoint.note(tick)
        if self.io.rezeroed:  # a re-zero survives a restart from this cycle on
            self.io.rezeroed = False
            self._checkpoint_due = True
        return tick.row

    def _cycle(self) -> Cycle:
        cycle = self.io.running.cycle
        assert cycle is not None  # the loop runs once the cycle exists
        return cycle

    def _save(self) -> None:
        """The checkpoint of the running cycle, written when this returns."""
        self.checkpoint.save(self.io.running.cfg, self._cycle())

    def _ramp_budget(self) -> int:
        """Begin the ramp-to-zero shutdown; the cycles it may take."""
        self.io.begin_shutdown()
        p = self.io.running.params
        # from beyond a lowered limit too (`compd.core.output`): the ramp is longer
        start_um = max(p.limit_um, abs(self.io.offset_um))
        return shutdown_ramp_cycles(start_um, p.slew_um_s, p.period_s)

    def _broken(self, exc: Exception, *, again: bool) -> int | None:
        """A cycle that raised even as a failed read: logged and alarmed; the shutdown
        ramp's budget to go on with, or None to stop now (a second break, a break
        during the ramp or in --once, or a shutdown policy that holds)."""
        cfg = self.io.running.cfg
        error = f"{type(exc).__name__}: {exc}"
        self.journal.log.error("cycle_broken", error=error, sequence=self.io.sequence,
                               offset_um=self.io.offset_um, shutdown=cfg.raw.faults.shutdown,
                               exc_info=True)
        self.journal.alarm("cycle_broken", "error", {"error": error})
        if again or self.once:
            return None  # the ramp cannot go on either: what is left is the checkpoint
        if cfg.raw.faults.shutdown != "ramp_to_zero" or self.io.dry_run or cfg.recorder_only:
            return None
        budget = self._ramp_budget()
        self.journal.log.info("shutdown_requested", policy="ramp_to_zero",
                              offset_um=self.io.offset_um, reason="cycle_broken")
        return budget

    def _stop(self, offset_um: float) -> int | None:
        """A stop was requested: the shutdown ramp's budget, or None to stop now (hold)."""
        cfg = self.io.running.cfg
        if (cfg.raw.faults.shutdown == "ramp_to_zero" and not self.io.dry_run
                and not cfg.recorder_only):  # a recorder-only run wrote nothing to ramp
            budget = self._ramp_budget()
            self.stop_requested = asyncio.Event()  # a second request ends the ramp
            self.journal.log.info("shutdown_requested", policy="ramp_to_zero",
                                  offset_um=offset_um, signal=self.stop_signal)
            return budget
        self.journal.log.info("shutdown_requested", policy="hold", offset_um=offset_um,
                              signal=self.stop_signal)
        return None

    async def run(self) -> int:
        cfg = self.io.running.cfg
        clock, log = self.clock, self.journal.log
        schedule = Schedule(cfg.real_period_s, clock.mono(), time_scale=cfg.raw.machine.time_scale)
        ramp_left: int | None = None
        broken = False
        while True:
            if self.between is not None and ramp_left is None:
                try:
                    await self.between()
                except Exception as exc:  # after the handover (reopening a sink): go on
                    self.journal.cycle_error("reload", exc)
            cfg = self.io.running.cfg
            started = clock.mono()
            try:
                result = await self.one_cycle(clock.at(started, schedule.machine_s))
            except Exception as exc:  # the cycle raised even as a failed read: broken
                again = broken or ramp_left is not None
                ramp_left = self._broken(exc, again=again)
                broken = broken or not (again or self.once)  # the exit status says so
                if ramp_left is None:
                    break
                schedule.advance(clock.mono())
                await pause(clock, self.stop_requested, schedule.wait_s(clock.mono()))
                continue
            self.metrics.cycle_seconds.observe(clock.mono() - started)
            if self.once:
                self._save()
                return 0 if result.in_force else 1
            if self._checkpoint_due:
                await self.checkpoint.save_async(self.io.running.cfg, self._cycle())
            if ramp_left is not None:
                ramp_left -= 1
                if result.shutdown_done or ramp_left <= 0:
                    log.info("shutdown_ramp_finished", offset_um=result.stage_um,
                             reached_zero=result.shutdown_done)
                    break
            elif self.stop_requested.is_set():
                ramp_left = self._stop(result.stage_um)
                if ramp_left is None:
                    break
            missed = schedule.advance(clock.mono())
            if missed:
                self.overruns += 1
                self.metrics.overruns.inc()
                log.warning("cycle_overrun", sequence=result.sequence,
                            skipped_deadlines=missed, overruns=self.overruns)
            if self.gc_policy is not None:
                self.gc_policy.after_cycle(schedule.wait_s(clock.mono()))
            await pause(clock, self.stop_requested, schedule.wait_s(clock.mono()))
            if self.stop_requested.is_set() and cfg.recorder_only:
                # nothing to ramp, and a cycle now would record a row off the sample
                # grid (or twice at one time), which compd fit refuses
                break
            if ramp_left is not None and self.stop_requested.is_set():
                log.warning("shutdown_ramp_interrupted", offset_um=self.io.offset_um)
                break
        self._save()
        log.info("daemon_stopped", cycles=self.cycles, overruns=self.overruns,
                 offset_um=self.io.offset_um, reloads=self.reloads(), signal=self.stop_signal,
                 broken=broken)
        return EX_SOFTWARE if broken else 0
