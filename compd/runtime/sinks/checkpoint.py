"""The checkpoint as a sink: the model's state saved atomically
(`compd.runtime.checkpoint`) every ``state.checkpoint_every`` cycles, at once
when the alarm comes or goes or the offset compd wants goes out of force
(so `compd health --state-dir` sees it as `--url` does), and on demand
(`save`: shutdown, `--once`, an operator hold). The cause saved is the first
one not in force since the last save (else the last cycle's): an offset
flapping in and out of force saves at most once a ``checkpoint_every`` window
out of turn, and `--state-dir` stays red until a window passes in force.

Beside the cycle's state it holds what `compd health --state-dir` judges, all
read from the reports it is fed: the last complete cycle's (`Row.in_force`)
wall and monotonic time (the cycle's own, read once by the loop), the boot it
happened in, and the last cycle's state and cause (an alarm, or an offset not
in force, is unhealthy however recent the rest). The config (the file's path,
``checkpoint_every``, the hashes saved) and the cycle whose state is saved
(`Tick.state`) are the tick's, or the caller's for a save outside a cycle. The
save's time (``saved_wall_s``, which a restart judges the state's age by, and
``saved_mono_s``) is the last cycle's noted: the time the state was stepped
to, on the daemon's clock; before any cycle nothing is saved (the checkpoint
on disk, if any, is still the state's).
A failed save is logged (``checkpoint_failed``) and never stops the loop. A
dry run saves nothing.

The state is taken and encoded on the loop's thread, at the cycle that asks
for it; the file is written (temp file, fsync, rename, fsync of the directory)
on one of the process's disk threads (`compd.runtime.diskwriter`, the state
directory's), in the order the saves were asked for. The loop awaits its due
saves (`save_async`: the machine's next cycle starts after its checkpoint is
on disk, while the other machines of the process cycle on); `save`
waits on the thread (shutdown, ``--once``, an operator's hold: the caller goes
on once the file is there).
"""

from __future__ import annotations

import asyncio
from concurrent.futures import Future
from typing import TYPE_CHECKING

from compd.core.faults import GAUGE_ALARM
from compd.runtime.diskwriter import PROCESS_DISK, DiskWriter
from compd.runtime.liveness import boot_id
from compd.runtime.sinks.base import CycleSink, StateSource, Tick
from compd.runtime.startup import checkpoint_path

if TYPE_CHECKING:
    from compd.config.loader import LoadedConfig
    from compd.runtime.journal import Journal
    from compd.runtime.statedir import StateDir

__all__ = ["CheckpointSink"]


class CheckpointSink(CycleSink):
    stage = "checkpoint"

    def __init__(self, *, dry_run: bool, journal: Journal,
                 writer: DiskWriter = PROCESS_DISK) -> None:
        #: the thread that writes the files (`compd.runtime.diskwriter`)
        self.writer = writer
        self._dry_run = dry_run
        self._journal = journal
        #: (wall, monotonic) time of the last complete cycle: the health evidence
        self.last_complete: tuple[float, float] | None = None
        #: (wall, monotonic) time of the last cycle noted: the saves' time
        self._last_cycle: tuple[float, float] | None = None
        #: the state directory the lock holds open (None without a lock: a dry run)
        self.directory: StateDir | None = None
        self._last_state: str | None = None
        #: the cause to save: the first not in force since the last save, else the last
        self._last_cause: str | None = None
        self._unhealthy_since_save = False
        #: whether the last cycle noted said alarm; whether the last save said in force
        self._alarm = False
        self._saved_healthy = True

    def feed(self, tick: Tick) -> None:
        if self.note(tick):
            self.save(tick.cfg, tick.state)

    def note(self, tick: Tick) -> bool:
        """Take the cycle's state; whether a checkpoint is due."""
        result = tick.row
        self._last_cycle = (result.wall_s, tick.mono_s)
        if result.in_force:
            self.last_complete = (result.wall_s, tick.mono_s)
        self._last_state = str(result.state)
        if not self._unhealthy_since_save:
            self._last_cause = str(result.cause)
            self._unhealthy_since_save = not result.healthy
        alarm = result.state.gauge >= GAUGE_ALARM
        if alarm != self._alarm:
            self._alarm = alarm
            return True
        if not result.healthy and self._saved_healthy:
            return True
        return result.sequence % tick.cfg.raw.state.checkpoint_every == 0

    def save(self, cfg: LoadedConfig, state: StateSource) -> None:
        """Save `state` (the running cycle) now under `cfg` (the one in force): the
        file is written when this returns (after every save asked for before it)."""
        job = self._submit(cfg, state)
        if job is not None:
            try:
                job.result()
            except Exception as exc:  # a failed checkpoint must not stop the loop
                self._failed(exc)
            else:
                self._saved()

    async def save_async(self, cfg: LoadedConfig, state: StateSource) -> None:
        """Save; the caller's task resumes once the file is written, the loop's
        thread free meanwhile."""
        job = self._submit(cfg, state)
        if job is not None:
            try:
                await asyncio.wrap_future(job)
            except Exception as exc:  # a failed checkpoint must not stop the loop
                self._failed(exc)
            else:
                self._saved()

    def _submit(self, cfg: LoadedConfig, source: StateSource) -> Future[None] | None:
        """The state encoded now and handed to the disk thread (None: nothing to
        write, a dry run, no cycle yet, or a state that cannot be stored, logged)."""
        if self._dry_run or self._last_cycle is None:
            return None
        from compd.runtime.checkpoint import encode_checkpoint, write_checkpoint

        try:
            saved_wall_s, saved_mono_s = self._last_cycle
            state = source.export_state()
            state.update(saved_mono_s=saved_mono_s, model_sha256=cfg.model_sha256,
                         config_sha256=cfg.config_sha256)
            last = self.last_complete
            if last is not None:  # what `compd health --state-dir` judges
                wall_s, mono_s = last
                state.update(last_complete_wall_s=wall_s, last_complete_mono_s=mono_s,
                             boot_id=boot_id())
            if self._last_state is not None:  # an alarm is unhealthy however recent
                state["last_state"] = self._last_state
            if self._last_cause is not None:  # so is an offset not in force
                state["last_cause"] = self._last_cause
            path = checkpoint_path(cfg)
            data = encode_checkpoint(path, state, wall_s=saved_wall_s)
        except Exception as exc:
            self._failed(exc)
            return None
        directory = self.directory
        return self.writer.submit(lambda: write_checkpoint(path, data, directory=directory),
                                  key=str(path.parent))

    def _saved(self) -> None:
        self._saved_healthy = not self._unhealthy_since_save
        self._unhealthy_since_save = False

    def _failed(self, exc: Exception) -> None:
        self._journal.log.error("checkpoint_failed", error=str(exc))
