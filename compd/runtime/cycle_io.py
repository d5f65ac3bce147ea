"""One cycle's I/O around the pure cycle, and every call the shell makes into
it: the one place where `compd.core.cycle.Cycle` is planned, committed,
exported, held, carried over a reload, or shut down.

Per cycle (`CycleIO.run`): read the channels (and the offset when read-back
is on, and the probe with [adaptation]) → `Cycle.plan` (its events logged
before the write: a write that hangs for its timeout must not delay the
cycle's fault lines) → write `plan.writes` → `Cycle.commit(outcome)`, the
final `Row` (a cycle with nothing to write, or a dry run, commits `WRITTEN`;
the events of a failed write's outcome are logged after it) → the `Tick`
the loop feeds its sinks.

Driver errors on read are a failed read (the cycle holds; the driver
reconnects by itself with its backoff). Anything else a read raises is a
driver's bug: it propagates (the loop's ``cycle_broken``: only a fresh
driver mends it). An exception from the cycle itself is logged (a
``cycle_error`` of stage ``step``) and the cycle is planned again as a
failed read, so the fault policy holds and then ramps; when that raises too,
it propagates. Write errors go back to the cycle as the commit's `Outcome`
(transient: retried next cycle; permanent: that output's writes stop),
counted per output the driver's error names (`DriverError.channels`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

from compd.config.loader import PROBE_NAMES, LoadedConfig
from compd.core.adaptation import ProbeReading
from compd.core.cycle import WRITTEN, Cycle, CycleParams, Outcome, Plan
from compd.core.events import Event, EventName
from compd.runtime.sinks.base import Tick
from drivers.base import Driver, Quality, Sample
from drivers.deadline import deadline
from drivers.errors import DriverError, WriteRejected

if TYPE_CHECKING:
    from compd.faces.telemetry import Metrics
    from compd.runtime.clock import Instant
    from compd.runtime.journal import Journal
    from compd.runtime.reload import Changes

__all__ = ["CycleIO", "Running"]


@dataclass
class Running:
    """What the loop runs, and what a SIGHUP reload swaps between two cycles."""

    cfg: LoadedConfig
    params: CycleParams
    driver: Driver | None = None
    cycle: Cycle | None = None


class CycleIO:
    def __init__(self, running: Running, *, dry_run: bool, metrics: Metrics,
                 journal: Journal) -> None:
        self.running = running
        self.dry_run = dry_run
        self.metrics = metrics
        self.journal = journal
        #: whether the last read heard the controller (None: none yet, or a new driver)
        self.read_ok: bool | None = None
        #: the endpoint whose connect failed (at start or for a reload): the first
        #: read that hears it logs ``controller_connected`` with it, so the log
        #: always says which controller the daemon is talking to
        self.unannounced: str | None = None
        #: who asked for a re-zero since the last cycle (`compd rezero`, OPC UA Rezero):
        #: applied at the start of the next one, on the daemon's loop
        self.rezero_requests: list[str] = []
        #: a re-zero happened (any source): the loop checkpoints at once and clears it
        self.rezeroed = False
        #: the names a read asks for, and the config and parameters they are of
        self._read_names: tuple[LoadedConfig, CycleParams, tuple[str, ...]] | None = None

    # -- the cycle, read to write ----------------------------------------------------

    async def run(self, at: Instant) -> Tick:
        """One cycle at `at` (its time, read once by the loop)."""
        cfg, driver, cycle = self.running.cfg, self.running.driver, self.running.cycle
        now_s, wall_s = at.machine_s, at.wall_s
        assert driver is not None and cycle is not None
        samples, readback, probe, off, got = await self._read(driver, cfg)
        axes = _axes_readback(got, cycle) if cycle.axes and samples is not None else None
        permitted, rezero = _permit(got, cfg), _bit(got, "rezero")
        if self.rezero_requests:
            for who in self.rezero_requests:
                self.journal.events([cycle.rezero(who, wall_s)])
            self.rezero_requests.clear()
            self.rezeroed = True
        try:
            if probe is not None:
                plan = cycle.plan(now_s, samples, readback, wall_s=wall_s, probe=probe,
                                  controller_off=off, permitted=permitted, rezero_bit=rezero,
                                  axes_readback=axes)
            elif axes is not None:
                plan = cycle.plan(now_s, samples, readback, wall_s=wall_s,
                                  controller_off=off, permitted=permitted, rezero_bit=rezero,
                                  axes_readback=axes)
            else:
                plan = cycle.plan(now_s, samples, readback, wall_s=wall_s,
                                  controller_off=off, permitted=permitted, rezero_bit=rezero)
        except Exception as exc:
            # the fault policy decides what reaches the machine: this cycle is a failed
            # read (hold, then ramp after hold_s); raises when it cannot even do that
            # (a machine that is off stays off for it: nothing is written)
            self.journal.cycle_error("step", exc)
            samples = None
            plan = cycle.plan(now_s, None, readback, wall_s=wall_s, controller_off=off)
        self.journal.events(plan.events)
        if any(e.name is EventName.REZERO for e in plan.events):
            self.rezeroed = True
        outcome = await self._write(driver, plan, cfg)
        row = cycle.commit(outcome)
        self.journal.events(row.write_events)
        confirmed = self.dry_run or self.running.params.recorder_only or (
            bool(plan.writes) and outcome.ok)
        return Tick(cfg=cfg, row=row, mono_s=at.mono_s, samples=samples,
                    confirmed=confirmed, read_ok=self.read_ok, state=cycle)

    async def _read(self, driver: Driver, cfg: LoadedConfig
                    ) -> tuple[dict[str, Sample] | None, float | None, ProbeReading | None,
                               str | None, Mapping[str, Sample]]:
        """The channels, the offset read back, the probe, and why the controller takes
        no offset now ([output] estop / machine_on / homed; None when it does or cannot
        say)."""
        params = self.running.params
        names = self._names(cfg, params)
        limit_s = _call_bound_s(cfg)
        try:
            # a timeout scope, not wait_for: no task started for every cycle's read;
            # drivers.deadline: a library's cancellation at its expiry is a timeout too
            async with deadline(limit_s):
                got = await driver.read(names)
        except (DriverError, TimeoutError) as exc:  # anything else is a driver's bug
            if self.read_ok is not False:
                self.journal.log.warning("read_failed", error=str(exc),
                                         type=type(exc).__name__)
            self.read_ok = False
            for name in getattr(exc, "channels", None) or ("*",):
                self.metrics.read_errors.labels(channel=name).inc()
            return None, None, None, None, {}
        if self.unannounced is not None:
            self.journal.log.info("controller_connected", endpoint=self.unannounced,
                                  after="connect_failed")
            self.unannounced = None
        elif self.read_ok is False:
            self.journal.log.info("controller_reconnected")
        self.read_ok = True
        readback: float | None = None
        if params.readback:
            rb = got.get(params.offset_name)
            if rb is not None and rb.quality is not Quality.BAD:
                readback = float(rb.value)
        probe = _probe_reading(got) if cfg.probes else None
        off = _controller_off(got) if cfg.states else None
        return {n: got[n] for n in cfg.channels if n in got}, readback, probe, off, got

    def _names(self, cfg: LoadedConfig, params: CycleParams) -> tuple[str, ...]:
        """Every name a read asks for: the channels, the offset and each axis's
        parameters read back, the probe and the controller's states; worked out
        once for a config (a reload brings another)."""
        known = self._read_names
        if known is not None and known[0] is cfg and known[1] is params:
            return known[2]
        names = list(cfg.channels)
        if params.readback:
            names.append(params.offset_name)
            names.extend(n for a in params.axes for n in a.names)
        names.extend(cfg.probes)
        names.extend(cfg.states)
        self._read_names = (cfg, params, tuple(names))
        return self._read_names[2]

    async def _write(self, driver: Driver, plan: Plan, cfg: LoadedConfig) -> Outcome:
        """The plan's writes (none in a dry run), and how they went. Bounded as the
        read is, by the cycle itself and not only by the driver's own request
        timeout: a write the driver failed to end is a transient failure at the
        bound, never a cycle that stops (and the heartbeat with it)."""
        if self.dry_run or not plan.writes:
            return WRITTEN
        limit_s = _call_bound_s(cfg)
        try:
            async with deadline(limit_s):
                await driver.write(plan.writes)
        except DriverError as exc:
            permanent = isinstance(exc, WriteRejected) and exc.permanent
            for name in exc.channels or ("*",):
                self.metrics.write_errors.labels(output=name).inc()
            return Outcome.failed(exc.channels, permanent=permanent, reason=str(exc))
        except TimeoutError:  # the cycle's bound, the driver's own timeout not kept
            self.metrics.write_errors.labels(output="*").inc()
            return Outcome.failed(None, reason=f"no answer within the cycle's {limit_s:g} s")
        except Exception as exc:  # a driver's bug: a transient write failure
            self.metrics.write_errors.labels(output="*").inc()
            return Outcome.failed(None, reason=f"{type(exc).__name__}: {exc}")
        self.journal.write_ok()
        return WRITTEN

    # -- the cycle outside plan and commit ----------------------------------------------------

    def request_rezero(self, who: str) -> bool:
        """A re-zero asked for by `who`, applied at the start of the next cycle on
        the daemon's loop; False before the cycle exists."""
        if self.running.cycle is None:
            return False
        self.rezero_requests.append(who)
        return True

    def operator_hold(self, on: bool, who: str) -> Event | None:
        """None when nothing changed; raises LookupError before the cycle exists."""
        cycle = self.running.cycle
        if cycle is None:
            raise LookupError("no cycle yet")
        return cycle.set_operator_hold(on, who)

    def carry_over(self, cfg: LoadedConfig, params: CycleParams, changes: Changes) -> None:
        """A reload: the cycle that continues the running one (`compd.runtime.reload.
        handover`: built from its state, then `Cycle.carry_over`)."""
        from compd.runtime.reload import handover

        assert self.running.cycle is not None
        self.running.cycle = handover(self.running.cycle, cfg, params, changes)

    def begin_shutdown(self) -> None:
        assert self.running.cycle is not None
        self.running.cycle.begin_shutdown()

    @property
    def sequence(self) -> int:
        return self.running.cycle.sequence if self.running.cycle is not None else 0

    @property
    def offset_um(self) -> float:
        cycle = self.running.cycle
        return cycle.output.current_um if cycle is not None else math.nan


def _probe_reading(got: dict[str, Sample]) -> ProbeReading:
    """The probe's value and counter as read (NaN where a read was bad or missing)."""
    def value(name: str) -> float:
        s = got.get(name)
        return float(s.value) if s is not None and s.quality is not Quality.BAD else math.nan

    return ProbeReading(value_um=value(PROBE_NAMES[0]), counter=value(PROBE_NAMES[1]))


def _axes_readback(got: Mapping[str, Sample], cycle: Cycle) -> dict[str, float | None]:
    """Each axis parameter as read back (None: missing or of bad quality)."""
    return {n: (float(s.value) if (s := got.get(n)) is not None and s.quality is not Quality.BAD
                else None) for n in cycle.axes.names}


def _bit(got: Mapping[str, Sample], name: str) -> bool | None:
    """A state input as read: non-zero is true; None when missing, bad or not a number."""
    s = got.get(name)
    if s is None or s.quality is Quality.BAD or not math.isfinite(s.value):
        return None
    return s.value != 0.0


def _permit(got: Mapping[str, Sample], cfg: LoadedConfig) -> bool | None:
    """[output] update_permitted as read: True without one; None (not permitted,
    said so) when it could not be read, a failed read included."""
    if "update_permitted" not in cfg.states:
        return True
    return _bit(got, "update_permitted")


def _controller_off(got: Mapping[str, Sample]) -> str | None:
    """Why the controller takes no offset now, from [output] estop, machine_on and
    homed as read (`compd.core.cycle`); None when it does or it cannot be told."""
    def bit(name: str) -> bool | None:
        return _bit(got, name)

    if bit("estop"):
        return "estop"
    if bit("machine_on") is False:
        return "machine_off"
    if bit("homed") is False:
        return "not_homed"
    return None


def _call_bound_s(cfg: LoadedConfig) -> float:
    """The cycle's own bound on its whole read and its whole write, whatever the
    driver does: the real period, or twice the request timeout when that is longer."""
    return max(cfg.real_period_s, 2.0 * cfg.raw.controller.timeout_s)
