"""SIGHUP in the running daemon: prepare a reload beside the loop, swap it in
between two cycles (`compd.runtime.reload` holds what may change and how the
cycle carries over).

`request` starts `prepare` in a task: the config and model are read and
validated in a worker thread while the loop keeps cycling; a changed
endpoint or address gets a new driver, connected before the swap. A request
while one is under way prepares again once it ends (the file may have
changed after it was read). A file that does not validate, or a change that
needs a restart, leaves the old config running (``reload_failed`` with the
key and the reason); so does any exception while the new cycle is built.
`swap` (the loop's ``between``) puts the prepared config in place: the
running config, parameters, cycle and driver (`compd.runtime.cycle_io.Running`),
then each sink's `reload` (a changed recorder is reopened, a changed metrics
endpoint restarted), ``reload_succeeded``.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Callable
from typing import TYPE_CHECKING

from compd.core.cycle import params_from_config
from compd.runtime.certcheck import check_certificates
from compd.runtime.driver_setup import connect

if TYPE_CHECKING:
    from compd.config.loader import LoadedConfig
    from compd.faces.telemetry import Metrics
    from compd.runtime.clock import Clock
    from compd.runtime.cycle_io import CycleIO
    from compd.runtime.journal import Journal
    from compd.runtime.reload import Changes
    from compd.runtime.sinks.base import CycleSink
    from drivers.base import Driver

__all__ = ["Reloader"]


class Reloader:
    def __init__(self, io: CycleIO, *, sinks: list[CycleSink], journal: Journal,
                 metrics: Metrics, clock: Clock,
                 build_driver: Callable[[LoadedConfig], Driver] | None = None) -> None:
        self.io = io
        self.sinks = sinks
        self.journal = journal
        self.metrics = metrics
        self.clock = clock
        self._build_driver = build_driver
        #: the reload being prepared, and what it produced for the loop to swap in
        self.task: asyncio.Task[None] | None = None
        self._again = False
        #: (config, changes, new driver or None, whether the new driver connected)
        self._pending: tuple[LoadedConfig, Changes, Driver | None, bool] | None = None
        self.reloads = 0

    def request(self) -> None:
        if self.task is not None and not self.task.done():
            self._again = True  # the file may have changed after it was read
            return
        self.journal.log.info("reload_requested", config=str(self.io.running.cfg.path))
        self.task = asyncio.get_running_loop().create_task(self._prepare())

    async def _prepare(self) -> None:
        from compd.errors import ConfigError
        from compd.runtime.reload import prepare

        while True:
            self._again = False
            cfg = self.io.running.cfg
            try:
                new, changes = await asyncio.to_thread(prepare, cfg)
                driver: Driver | None = None
                connected = False
                if changes.controller:
                    driver = self._new_driver(new)
                    connected = await connect(driver, new, self.journal.log)
            except ConfigError as exc:
                self.journal.log.error("reload_failed", key=exc.key, reason=exc.reason,
                                       config=str(cfg.path), kept=cfg.config_sha256)
            except Exception as exc:  # never the loop's end: the old config keeps running
                self.journal.log.error("reload_failed", key="",
                                       reason=f"{type(exc).__name__}: {exc}",
                                       config=str(cfg.path), kept=cfg.config_sha256)
            else:
                if self._pending is not None and self._pending[2] is not None:
                    await self._pending[2].close()  # superseded before it was swapped in
                self._pending = (new, changes, driver, connected)
            if not self._again:
                return

    def _new_driver(self, cfg: LoadedConfig) -> Driver:
        if self._build_driver is not None:
            return self._build_driver(cfg)
        from compd.runtime.driver_setup import build_driver

        return build_driver(cfg)

    async def cancel(self) -> None:
        task = self.task
        if task is not None and not task.done():
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        if self._pending is not None and self._pending[2] is not None:
            await self._pending[2].close()
        self._pending = None

    async def swap(self) -> None:
        """Put the prepared config (if any) in place of the running one."""
        if self._pending is None:
            return
        new, changes, driver, connected = self._pending
        self._pending = None
        running, log = self.io.running, self.journal.log
        old_cfg, old_driver = running.cfg, running.driver
        try:
            params = params_from_config(new, dry_run=self.io.dry_run)
            self.io.carry_over(new, params, changes)
        except Exception as exc:  # never the loop's end: the old config keeps running
            log.error("reload_failed", key="", reason=f"{type(exc).__name__}: {exc}",
                      config=str(new.path), kept=old_cfg.config_sha256, exc_info=True)
            if driver is not None:
                with contextlib.suppress(Exception):
                    await driver.close()
            return
        running.cfg, running.params = new, params
        if driver is not None:
            running.driver = driver
            self.io.read_ok = None
            self.io.unannounced = None if connected else new.raw.controller.endpoint
            if old_driver is not None:
                await old_driver.close()
        self.reloads += 1
        for sink in self.sinks:
            sink.reload(new, changes)
        log.info("reload_succeeded", changed=list(changes.keys), restarted=changes.names(),
                 config_sha256=new.config_sha256, model_sha256=new.model_sha256,
                 was_config_sha256=old_cfg.config_sha256, was_model_sha256=old_cfg.model_sha256,
                 model=new.model.name,
                 filters="restart_at_steady_state" if changes.model else "carried_over",
                 offset_um=self.io.offset_um)
        log.info("outputs_configured", outputs={n: a.describe() for n, a in new.outputs.items()},
                 config_sha256=new.config_sha256, model_sha256=new.model_sha256,
                 dry_run=self.io.dry_run)
        check_certificates(new, self.metrics, log, wall_s=self.clock.wall())
