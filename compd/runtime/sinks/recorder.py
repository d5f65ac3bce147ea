"""The recorder as a sink: each cycle's report into SQLite (`compd.runtime.recorder`)
as its `compd.core.plan.Row.record` (the wall-clock time is the cycle's).

Compensation never stops for the recorder: one that cannot open is logged
(``recorder_unavailable``) and the daemon runs without it; one that fails
while running drops rows (counted in ``compd_records_dropped``) and raises
its alarm (``recorder_failing``, then ``recorder_recovered``). Retention is a
row count (one row per cycle), never judged by a clock that can jump. A
reload that changes ``[recorder]`` closes it and opens the new one.

Commits run on the process's disk thread (`compd.runtime.diskwriter`; the
rows formatted here, on the loop's thread): a commit that failed there is
counted and alarmed at the next cycle's feed.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

from compd.runtime.sinks.base import CycleSink, Tick

if TYPE_CHECKING:
    from compd.config.loader import LoadedConfig
    from compd.faces.telemetry import Metrics
    from compd.runtime.journal import Journal
    from compd.runtime.recorder import Recorder
    from compd.runtime.reload import Changes

__all__ = ["RecorderSink"]


class RecorderSink(CycleSink):
    stage = "record"

    def __init__(self, *, dry_run: bool, metrics: Metrics, journal: Journal) -> None:
        self._dry_run = dry_run
        self._metrics = metrics
        self._journal = journal
        #: the open recorder (None: none configured, a dry run, or it could not open)
        self.recorder: Recorder | None = None
        self._alarm = False
        #: the open recorder's drops already counted in ``compd_records_dropped``
        self._dropped = 0

    @property
    def log(self) -> Any:
        return self._journal.log

    async def open(self, cfg: LoadedConfig) -> None:
        self.open_now(cfg)

    def open_now(self, cfg: LoadedConfig) -> None:
        path = cfg.recorder_path
        if self._dry_run or path is None:
            return
        from compd.runtime.diskwriter import PROCESS_DISK
        from compd.runtime.recorder import Recorder

        rc = cfg.raw.recorder
        keep_rows = (max(1, math.ceil(rc.retention_days * 86400.0 / cfg.period_s))
                     if rc.retention_days else None)
        recorder = Recorder(path, commit_every=rc.commit_every, keep_rows=keep_rows,
                            writer=PROCESS_DISK)
        try:
            recorder.open()
        except Exception as exc:  # compensation never stops for the recorder
            self.log.error("recorder_unavailable", path=str(path), error=str(exc))
            return
        self.recorder = recorder
        self._dropped = 0

    def feed(self, tick: Tick) -> None:
        recorder = self.recorder
        if recorder is None:
            return
        recorder.record(tick.row.record)
        dropped = recorder.dropped  # this cycle's, or a commit's on the disk thread
        if dropped > self._dropped:
            self._metrics.records_dropped.inc(dropped - self._dropped)
            self._dropped = dropped
        alarm = bool(recorder.alarm)
        if alarm != self._alarm:
            # compensation goes on either way; the alarm tells that samples are lost
            self._alarm = alarm
            self._metrics.recorder_alarm.set(1 if alarm else 0)
            if alarm:
                self.log.error("recorder_failing", error=recorder.last_error,
                               dropped=recorder.dropped)
            else:
                self.log.info("recorder_recovered", dropped=recorder.dropped)

    def reload(self, cfg: LoadedConfig, changes: Changes) -> None:
        if changes.recorder:
            self.close_now()
            self.open_now(cfg)

    async def close(self) -> None:
        self.close_now()

    def close_now(self) -> None:
        recorder, self.recorder = self.recorder, None
        if recorder is not None:
            recorder.close()
