"""The checkpoint as a sink: the model's state saved atomically
(`compd.runtime.checkpoint`) every ``state.checkpoint_every`` cycles, at once
when the alarm comes or goes or the offset compd wants goes out of force
(so `compd health --state-dir` sees it as `--url` does), and on demand
(`save`: shutdown, `--once`, an operator hold). The cause saved is the first
one not in force since the last save (else the last cycle's): an offset
flapping in and out of force saves at most once a ``checkpoint_every`` window
out of turn, and `--state-dir` stays red until a window passes in force.

Beside the cycle's state it holds what `compd health --state-dir` judges:
the last complete cycle's wall and monotonic time, the boot it happened in,
and the last cycle's state and cause (an alarm, or an offset not in force, is
unhealthy however recent the rest).
A failed save is logged (``checkpoint_failed``) and never stops the loop. A
dry run saves nothing.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from compd.core.faults import GAUGE_ALARM
from compd.runtime.liveness import boot_id
from compd.runtime.sinks.base import CycleSink, Tick
from compd.runtime.startup import checkpoint_path

if TYPE_CHECKING:
    from compd.config.loader import LoadedConfig
    from compd.runtime.clock import Clock
    from compd.runtime.journal import Journal
    from compd.runtime.reload import Changes
    from compd.runtime.statedir import StateDir

__all__ = ["CheckpointSink"]


class CheckpointSink(CycleSink):
    stage = "checkpoint"

    def __init__(self, cfg: LoadedConfig, *, dry_run: bool, clock: Clock, journal: Journal,
                 export: Callable[[], dict[str, Any]],
                 last_complete: Callable[[], tuple[float, float] | None]) -> None:
        self._cfg = cfg
        self._dry_run = dry_run
        self._clock = clock
        self._journal = journal
        self._export = export
        self._last_complete = last_complete
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
            self.save()

    def note(self, tick: Tick) -> bool:
        """Take the cycle's state; whether a checkpoint is due."""
        result = tick.row
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
        return result.sequence % self._cfg.raw.state.checkpoint_every == 0

    def reload(self, cfg: LoadedConfig, changes: Changes) -> None:
        self._cfg = cfg

    def save(self) -> None:
        if self._dry_run:
            return
        from compd.runtime.checkpoint import save_checkpoint

        cfg = self._cfg
        try:
            state = self._export()
            state.update(saved_mono_s=self._clock.mono(), model_sha256=cfg.model_sha256,
                         config_sha256=cfg.config_sha256)
            last = self._last_complete()
            if last is not None:  # what `compd health --state-dir` judges
                wall_s, mono_s = last
                state.update(last_complete_wall_s=wall_s, last_complete_mono_s=mono_s,
                             boot_id=boot_id())
            if self._last_state is not None:  # an alarm is unhealthy however recent
                state["last_state"] = self._last_state
            if self._last_cause is not None:  # so is an offset not in force
                state["last_cause"] = self._last_cause
            save_checkpoint(checkpoint_path(cfg), state, directory=self.directory)
            self._saved_healthy = not self._unhealthy_since_save
            self._unhealthy_since_save = False
        except Exception as exc:  # a failed checkpoint must not stop the loop
            self._journal.log.error("checkpoint_failed", error=str(exc))
