"""`compd demo`: the simulated machine on loopback, and the real daemon against it.

The demo process serves one simulated machine (thermal plant + simulated
controller of the chosen protocol) on 127.0.0.1 and starts ``compd run`` as a
separate process against it, with a bundled calibrated model, both at the
same speed-up (the daemon's ``machine.time_scale``). The plant reports the
thermal growth at the tool and the error left after the offset the daemon
wrote (error = growth - offset), so the result is measured through the wire:

- uncompensated range: max - min of the growth over the run
- compensated range: max - min of the error over the run
- range reduction: their ratio (docs/models.md §11), fit %: offset vs growth
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
import signal
import socket
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from compd.errors import ConfigError
from compd.infiles import load_model
from drivers.sim.base import SimController
from drivers.sim.focas_server import FocasSimController
from drivers.sim.linuxcnc_machine import LinuxCncSimController
from drivers.sim.machine import SimMachine
from drivers.sim.renamed import current_name, warn_former
from models import tomltext
from models.quality import fit_percent

#: channel settings the demo config gives each simulated channel it reads
_TEMPERATURE = {"unit": "degC", "range": [-20.0, 150.0], "max_rate_per_s": 0.5}
_CHANNEL_SETTINGS: dict[str, dict[str, Any]] = {
    "bearing": _TEMPERATURE, "motor": _TEMPERATURE, "column": _TEMPERATURE,
    "table": _TEMPERATURE, "ambient": _TEMPERATURE,
    "spindle_rpm": {"unit": "rpm", "range": [0.0, 30000.0]},
    "power_kw": {"unit": "kW", "range": [-1.0, 200.0]},
}


#: real seconds `compd run` may take to start and complete its first cycle
_READY_TIMEOUT_S = 30.0


@dataclass(frozen=True)
class DemoResult:
    protocol: str
    hours: float
    uncompensated_range_um: float
    compensated_range_um: float
    range_reduction: float
    fit_percent: float
    daemon_exit: int
    plant_ticks: int
    history: dict[str, np.ndarray]

    def summary(self) -> dict[str, float]:
        return {"uncompensated_range_um": self.uncompensated_range_um,
                "compensated_range_um": self.compensated_range_um,
                "range_reduction": self.range_reduction,
                "fit_percent": self.fit_percent}


def daemon_config(sim: SimController, *, model: str, period_s: float, time_scale: float,
                  state_dir: Path, limit_um: float = 200.0, slew_um_s: float = 0.2,
                  extra_channels: tuple[str, ...] = ("spindle_rpm",)) -> dict[str, Any]:
    """A daemon config document for the simulated controller `sim`."""
    needed = load_model(model).channels
    channels: dict[str, Any] = {}
    # a model's term on a channel's former name (speed_rpm) reads that channel, under
    # the model's name and not twice
    former = {current_name(n) for n in needed if current_name(n) != n}
    for name in sorted(needed | (set(extra_channels) - former)):
        served = current_name(name)
        if served not in sim.channels:
            raise ConfigError("", f"--model {model}: the simulated machine has no channel "
                                  f"{name!r}; it has {sorted(sim.channels)}")
        if served != name:
            warn_former(name, f"--model {model}")
        settings = dict(_CHANNEL_SETTINGS.get(served, {"unit": "ratio",
                                                       "range": [-1e6, 1e6]}))
        settings["stale_after_s"] = 10.0 * period_s
        channels[name] = {"address": sim.channels[served].model_dump(), **settings}
    real_period_s = period_s / time_scale
    controller: dict[str, Any] = {
        "protocol": sim.protocol, "endpoint": sim.endpoint,
        "timeout_s": round(min(0.45 * real_period_s, 0.5), 6),
        "connect_timeout_s": 2.0,
        "backoff": {"initial_s": min(0.05, real_period_s), "cap_s": 0.5},
    }
    if sim.protocol == "opcua":
        controller["security"] = {"policy": "None", "insecure": True}
    if isinstance(sim, FocasSimController):  # its library is the twin's own, not the protocol's
        controller["focas"] = {"library_path": str(sim.library_path)}
    if isinstance(sim, LinuxCncSimController):  # its HAL names are the run's own
        controller["linuxcnc"] = {"component": sim.component}
    outputs = sim.outputs_map
    return {
        "machine": {"name": f"demo-{sim.protocol}", "period_s": period_s,
                    "time_scale": time_scale},
        "controller": controller,
        "channels": channels,
        "model": {"file": model},
        "output": {"offset": outputs["offset"].model_dump(),
                   "heartbeat": outputs["heartbeat"].model_dump(),
                   "status": outputs["status"].model_dump(),
                   "unit": "um", "sign": 1, "limit_um": limit_um, "slew_um_s": slew_um_s,
                   "readback": True},
        "faults": {"hold_s": 30.0 * period_s, "shutdown": "hold"},
        "state": {"dir": str(state_dir), "checkpoint_every": 30},
        "recorder": {"enabled": True, "commit_every": 50},
        "telemetry": {"log_format": "json", "log_level": "warning"},
    }


def _log_tail(path: Path, chars: int = 2000) -> str:
    return path.read_text(errors="replace")[-chars:]


async def _keep_publishing(sim: SimController, values: dict[str, float],
                           real_period_s: float) -> None:
    while True:
        await sim.publish(values)
        await asyncio.sleep(real_period_s)


async def start_daemon_at_rest(machine: SimMachine, config_path: Path, log_path: Path,
                               notify_path: Path) -> asyncio.subprocess.Process:
    """`start_daemon` while the machine stands at rest: primed, its sensors
    published again each period (a controller keeps publishing a cold machine)
    until the daemon is ready; the program starts after."""
    at_rest = await machine.prime()
    refresh = asyncio.ensure_future(_keep_publishing(machine.controller, at_rest,
                                                     machine.period_s / machine.speedup))
    try:
        return await start_daemon(config_path, log_path, notify_path)
    finally:
        refresh.cancel()
        await asyncio.gather(refresh, return_exceptions=True)


async def start_daemon(config_path: Path, log_path: Path,
                        notify_path: Path) -> asyncio.subprocess.Process:
    """Start `compd run` and wait for its sd_notify READY=1 (its first complete
    cycle), so the plant's program starts on a daemon that is already
    compensating: a daemon started on a warm machine with no checkpoint has
    no way to know how warm it is."""
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(notify_path))
    sock.setblocking(False)
    log = log_path.open("wb")
    try:
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "compd", "run", str(config_path),
            stdin=asyncio.subprocess.DEVNULL, stdout=log, stderr=log,
            env={**os.environ, "NOTIFY_SOCKET": str(notify_path)})
        loop = asyncio.get_running_loop()

        async def ready() -> None:
            while b"READY=1" not in await loop.sock_recv(sock, 4096):
                pass
        waiter = asyncio.ensure_future(ready())
        exited = asyncio.ensure_future(proc.wait())
        done, _ = await asyncio.wait({waiter, exited}, timeout=_READY_TIMEOUT_S,
                                     return_when=asyncio.FIRST_COMPLETED)
        waiter.cancel()
        exited.cancel()
        await asyncio.gather(waiter, exited, return_exceptions=True)
        if waiter in done:
            return proc
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
        raise RuntimeError(f"compd run did not become ready (exit status {proc.returncode}); "
                           f"its log ends:\n{_log_tail(log_path)}")
    finally:
        log.close()
        sock.close()


async def _report(machine: SimMachine, progress: Callable[[float], None]) -> None:
    while True:
        progress(machine.plant.time_s / 3600.0)
        await asyncio.sleep(0.5)


async def run_demo(protocol: str = "opcua", *, hours: float = 8.0, wall_s: float = 60.0,
                   model: str = "sim_machine", seed: int = 7, program: str = "spectrum",
                   workdir: Path | None = None,
                   progress: Callable[[float], None] | None = None) -> DemoResult:
    """Serve the simulated machine, run `compd run` against it, return the figures.
    `progress`, when given, hears the machine hours done about twice a second."""
    from drivers.sim.programs import make_program
    from drivers.sim.registry import make_sim_controller

    period_s = load_model(model).period_s
    time_scale = hours * 3600.0 / wall_s
    with contextlib.ExitStack() as stack:
        work = workdir or Path(stack.enter_context(tempfile.TemporaryDirectory(
            prefix="compd-demo-")))
        sim = make_sim_controller(protocol)
        await sim.start()
        try:
            machine = SimMachine(sim, program=make_program(program, seed=seed), seed=seed,
                                 period_s=period_s, speedup=time_scale, repeat=False,
                                 record=True)
            doc = daemon_config(sim, model=model, period_s=period_s, time_scale=time_scale,
                                state_dir=work / "state")
            config_path = work / "compd.toml"
            config_path.write_text(tomltext.dumps(doc), encoding="utf-8")
            daemon = await start_daemon_at_rest(machine, config_path, work / "daemon.log",
                                                work / "notify")
            watch = asyncio.create_task(_report(machine, progress)) if progress else None
            try:
                await machine.run(until_s=hours * 3600.0)
                if progress is not None:
                    progress(machine.plant.time_s / 3600.0)
            finally:
                if watch is not None:
                    watch.cancel()
                    await asyncio.gather(watch, return_exceptions=True)
                if daemon.returncode is None:
                    daemon.send_signal(signal.SIGTERM)
                try:
                    rc = await asyncio.wait_for(daemon.wait(), 15.0)
                except TimeoutError:
                    daemon.kill()
                    rc = await daemon.wait()
        finally:
            await sim.stop()
        if rc != 0:
            raise RuntimeError(f"compd run exited {rc}; its log ends:\n"
                               f"{_log_tail(work / 'daemon.log')}")
    hist = machine.history_arrays()
    growth, error = hist["growth_um"], hist["error_um"]
    unc = float(np.ptp(growth))
    comp = float(np.ptp(error))
    return DemoResult(
        protocol=protocol, hours=hours, uncompensated_range_um=unc,
        compensated_range_um=comp,
        range_reduction=unc / comp if comp > 0 else math.inf,
        fit_percent=fit_percent(growth, hist["offset_um"]),
        daemon_exit=rc, plant_ticks=machine.ticks, history=hist)
