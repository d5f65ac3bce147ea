"""The operator status page as a sink ([faces.http]): each cycle's snapshot
published to the `compd.faces.status.StatusBoard`, which the HTTP threads
only read. The board is the daemon's whether or not the page is served: the
journal lists warnings and errors on it (`compd.runtime.journal`).
"""

from __future__ import annotations

from compd.faces.status import StatusBoard
from compd.runtime.sinks.base import CycleSink, Tick

__all__ = ["StatusSink"]


class StatusSink(CycleSink):
    stage = "status_page"

    def __init__(self, board: StatusBoard, *, dry_run: bool) -> None:
        self.board = board
        self._dry_run = dry_run

    def feed(self, tick: Tick) -> None:
        if tick.cfg.raw.faces.http.enabled:
            self.board.publish(tick.row, tick.cfg, dry_run=self._dry_run)
