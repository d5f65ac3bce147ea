"""Shared pieces of the daemon benchmarks (bench_daemon_*.py).

- `start_sim`: one `compd sim --protocol P --json` process (the simulated
  machine: plant + controller), its endpoint and addresses;
- `config_doc`: a daemon config document for such a simulated controller, with
  the production defaults (recorder on, commit every 10, checkpoint every 60,
  JSON logs at info);
- `TimedDriver` and `TimedDaemon`: timing hooks *around* the unchanged daemon
  (a pass-through driver that times its calls; a subclass that wraps its
  loop's cycle and its recorder, telemetry and checkpoint sinks and notes each
  cycle's start), so the daemon's own cost = cycle time - time inside the driver;
- `/proc` readers: resident memory and CPU seconds of a process.
"""

from __future__ import annotations

import asyncio
import json
import math
import os
import subprocess
import sys
import time
from collections.abc import Awaitable, Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from compd.core.plan import Row
from compd.runtime.daemon import Daemon
from drivers.base import Driver, Sample
from drivers.errors import ControllerTimeout

#: the sensors a simulated controller offers (growth/error are the plant's truth)
SENSORS: tuple[str, ...] = ("bearing", "motor", "column", "table", "ambient", "spindle_rpm",
                            "power_kw")
_TEMPERATURE: dict[str, Any] = {"unit": "degC", "range": [-20.0, 150.0],
                                "max_rate_per_s": 1.0}
_SETTINGS: dict[str, dict[str, Any]] = {
    "bearing": _TEMPERATURE, "motor": _TEMPERATURE, "column": _TEMPERATURE,
    "table": _TEMPERATURE, "ambient": _TEMPERATURE,
    "spindle_rpm": {"unit": "rpm", "range": [0.0, 30000.0]},
    "power_kw": {"unit": "kW", "range": [-1.0, 200.0]},
}


def percentile(values: Sequence[float], q: float) -> float:
    if not values:
        return math.nan
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, round(q * (len(ordered) - 1)))]


def mean(values: Sequence[float]) -> float:
    return sum(values) / len(values) if values else math.nan


# -- simulated machines ----------------------------------------------------------------

@dataclass
class SimProcess:
    proc: subprocess.Popen[str]
    desc: dict[str, Any]

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10.0)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


def start_sim(protocol: str, *, speedup: float = 1.0, seed: int = 0) -> SimProcess:
    """`compd sim --protocol P --json` in its own process; waits for its JSON line."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "compd", "sim", "--protocol", protocol, "--json",
         "--speedup", repr(speedup), "--seed", str(seed)],
        stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
        text=True)
    if proc.stdout is None:
        raise RuntimeError("no stdout pipe")
    line = proc.stdout.readline()
    if not line:
        proc.wait()
        raise RuntimeError(f"compd sim --protocol {protocol} exited {proc.returncode}")
    return SimProcess(proc, json.loads(line))


def config_doc(desc: Mapping[str, Any], *, state_dir: Path, period_s: float = 1.0,
               time_scale: float = 1.0, model: str = "sp2",
               sensors: Sequence[str] = SENSORS, log_level: str = "info",
               checkpoint_every: int = 60) -> dict[str, Any]:
    """A daemon config for the simulated controller `desc` (`compd sim --json`)."""
    channels: dict[str, Any] = {}
    for name in sensors:
        settings = dict(_SETTINGS.get(name, {"unit": "ratio", "range": [-1e6, 1e6]}))
        settings["stale_after_s"] = 10.0 * period_s
        channels[name] = {"address": desc["channels"][name], **settings}
    real_period_s = period_s / time_scale
    controller: dict[str, Any] = {
        "protocol": desc["protocol"], "endpoint": desc["endpoint"],
        "timeout_s": round(min(0.45 * real_period_s, 0.5), 6),
        "connect_timeout_s": 5.0,
        "backoff": {"initial_s": min(0.05, real_period_s), "cap_s": 0.5},
    }
    if desc["protocol"] == "opcua":
        controller["security"] = {"policy": "None", "insecure": True}
    outputs = desc["outputs"]
    return {
        "machine": {"name": f"bench-{desc['protocol']}", "period_s": period_s,
                    "time_scale": time_scale},
        "controller": controller,
        "channels": channels,
        "model": {"file": model},
        "output": {"offset": outputs["offset"], "heartbeat": outputs["heartbeat"],
                   "status": outputs["status"], "unit": "um", "sign": 1,
                   "limit_um": 200.0, "slew_um_s": 1.0, "readback": True},
        "faults": {"hold_s": 60.0, "shutdown": "hold"},
        "state": {"dir": str(state_dir), "checkpoint_every": checkpoint_every},
        "recorder": {"enabled": True, "commit_every": 10, "retention_days": 30},
        "telemetry": {"log_format": "json", "log_level": log_level},
    }


def write_config(doc: Mapping[str, Any], path: Path) -> Path:
    from models import tomltext

    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(tomltext.dumps(dict(doc)), encoding="utf-8")
    return path


# -- timing hooks ------------------------------------------------------------------------

def leaked_cancel(exc: BaseException) -> bool:
    """asyncua's ``wait_for2.CancelledWithResultError``: a CancelledError subclass
    that escapes the OPC UA driver when its ``asyncio.timeout`` races the answer
    (``asyncio.timeout`` turns only an exact CancelledError into TimeoutError)."""
    return isinstance(exc, asyncio.CancelledError) and type(exc) is not asyncio.CancelledError


class TimedDriver:
    """Pass-through to a real driver; sums the seconds spent in read/write.

    A leaked cancel (`leaked_cancel`) is counted in `leaked` and handed to the
    daemon as the ControllerTimeout the driver means to raise, so the benchmark
    measures the daemon rather than stopping on that driver bug.
    """

    def __init__(self, inner: Driver) -> None:
        self.inner = inner
        self.protocol = inner.protocol
        self.io_s = 0.0
        self.leaked = 0

    def _timeout(self, exc: BaseException, what: str) -> ControllerTimeout:
        self.leaked += 1
        return ControllerTimeout(f"{what}: {type(exc).__name__} leaked by the driver")

    @property
    def connected(self) -> bool:
        return self.inner.connected

    async def connect(self) -> None:
        await self.inner.connect()

    async def read(self, names: Sequence[str]) -> dict[str, Sample]:
        t0 = time.perf_counter()
        try:
            return await self.inner.read(names)
        except asyncio.CancelledError as exc:
            if not leaked_cancel(exc):
                raise
            raise self._timeout(exc, "read") from None
        finally:
            self.io_s += time.perf_counter() - t0

    async def write(self, values: Mapping[str, float]) -> None:
        t0 = time.perf_counter()
        try:
            await self.inner.write(values)
        except asyncio.CancelledError as exc:
            if not leaked_cancel(exc):
                raise
            raise self._timeout(exc, "write") from None
        finally:
            self.io_s += time.perf_counter() - t0

    async def close(self) -> None:
        await self.inner.close()


@dataclass
class CycleTimes:
    """Per-cycle figures a `TimedDaemon` collects (seconds; monotonic starts)."""

    start: list[float] = field(default_factory=list)
    total: list[float] = field(default_factory=list)
    io: list[float] = field(default_factory=list)
    record: list[float] = field(default_factory=list)
    telemetry: list[float] = field(default_factory=list)
    checkpoint_s: float = 0.0
    checkpoints: int = 0

    def lateness(self, period_s: float, since: float = -math.inf,
                 until: float = math.inf) -> list[float]:
        """Cycle start - its deadline. The daemon's deadlines are the first
        cycle's start + k·period (skipped by whole periods after an overrun),
        so each start is compared with the nearest such instant. The last cycle
        is left out: it follows the stop request, not a deadline. `since`/`until`:
        only starts in that window (monotonic seconds)."""
        if len(self.start) < 3:
            return []
        t0 = self.start[0]
        out = []
        for s in self.start[1:-1]:
            if not since <= s < until:
                continue
            x = s - t0
            out.append(x - period_s * math.floor(x / period_s + 0.5))
        return out


class TimedDaemon(Daemon):
    """The daemon, unchanged, with timing around its cycle and its sinks: its
    loop's `one_cycle` (read to the last sink, the checkpoint excluded), the
    recorder's and telemetry's `feed`, and each checkpoint `save`."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.times = CycleTimes()
        #: set when the first cycle has started
        self.first_cycle = asyncio.Event()
        #: request a stop after this many cycles (None: run until stopped)
        self.stop_after: int | None = None
        setattr(self.loop, "one_cycle", self._timed_cycle(self.loop.one_cycle))  # noqa: B010
        setattr(self.recorder, "feed", _timed(self.recorder.feed, self.times.record))  # noqa: B010
        setattr(self.telemetry, "feed",  # noqa: B010
                _timed(self.telemetry.feed, self.times.telemetry))
        save = self.checkpoint.save

        def timed_save(*args: Any) -> None:  # the config in force, as the loop passes it
            t0 = time.perf_counter()
            save(*args)
            self.times.checkpoint_s += time.perf_counter() - t0
            self.times.checkpoints += 1

        setattr(self.checkpoint, "save", timed_save)  # noqa: B010

    def _timed_cycle(self, one_cycle: Callable[[Any], Awaitable[Row]]
                     ) -> Callable[[Any], Awaitable[Row]]:
        async def timed(at: Any) -> Row:  # the cycle's time (`Instant`)
            driver = self.running.driver
            io0 = driver.io_s if isinstance(driver, TimedDriver) else 0.0
            self.times.start.append(time.monotonic())
            self.first_cycle.set()
            tp = time.perf_counter()
            result = await one_cycle(at)
            self.times.total.append(time.perf_counter() - tp)
            self.times.io.append((driver.io_s - io0) if isinstance(driver, TimedDriver)
                                 else 0.0)
            if self.stop_after is not None and self.loop.cycles >= self.stop_after:
                self.request_stop()
            return result

        return timed


def _timed(feed: Callable[[Any], None], into: list[float]) -> Callable[[Any], None]:
    def timed(tick: Any) -> None:
        t0 = time.perf_counter()
        feed(tick)
        into.append(time.perf_counter() - t0)

    return timed


# -- process-wide counters ---------------------------------------------------------------

def count_sends() -> list[int]:
    """Count the socket sends of every asyncio transport of this process (the
    drivers' requests: one send per Modbus request or OPC UA message chunk)."""
    from asyncio import selector_events

    sent = [0]
    cls: Any = selector_events._SelectorSocketTransport
    write = cls.write

    def counted(self: Any, data: Any) -> None:
        sent[0] += 1
        write(self, data)

    cls.write = counted
    return sent


def watch_gc_pauses() -> list[tuple[float, int, float]]:
    """Every garbage collection of this process from now on, as (monotonic time
    at its end, generation, seconds) appended to the list returned."""
    import gc

    pauses: list[tuple[float, int, float]] = []
    t0 = [0.0]

    def on_gc(phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            t0[0] = time.perf_counter()
        else:
            pauses.append((time.monotonic(), info["generation"], time.perf_counter() - t0[0]))

    gc.callbacks.append(on_gc)
    return pauses


# -- /proc ---------------------------------------------------------------------------------

def rss_mb(pid: int) -> float:
    """VmRSS of `pid` in MB (1e6 bytes), NaN when the process is gone."""
    try:
        text = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return math.nan
    for line in text.splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024 / 1e6
    return math.nan


def cpu_s(pid: int) -> float:
    """User + system CPU seconds of `pid` (NaN when gone)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return math.nan
    ticks = os.sysconf("SC_CLK_TCK")
    return (int(fields[11]) + int(fields[12])) / ticks


def stop_processes(procs: Sequence[subprocess.Popen[Any]], timeout_s: float = 60.0) -> None:
    """SIGTERM each of `procs` (the simulator farms), then wait for each, killing
    one that has not ended within `timeout_s`."""
    for proc in procs:
        proc.terminate()
    for proc in procs:
        try:
            proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
