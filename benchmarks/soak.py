"""Soak: `compd run` (a subprocess) against the simulated Modbus controller for
hours of machine time at a speed-up, with a random fault from the issue's list
every few machine minutes: open sensor (raw 32767), a ±50 K spike for one
sample, a stuck sensor, a controller restart that forgets the offset, link
loss for 30 machine seconds, write rejection (Modbus exception 4) for 30
machine seconds. The bearing temperature follows a slow warm-up and cycle so
the offset keeps moving.

Reports (JSON on stdout): the daemon's resident memory (VmRSS) after warm-up
and at the end, its open file descriptors and threads over the run (asyncio
tasks are not visible from outside the process; threads are), the largest
offset step per write and per machine second against the slew limit, the
faults injected, and the exit status after SIGTERM. Targets: RSS growth under
5 MB, fd and thread counts flat.

    .venv/bin/python benchmarks/soak.py --hours 1 --speedup 30 --fault-every-min 4
"""

from __future__ import annotations

import argparse
import asyncio
import itertools
import json
import math
import os
import random
import signal
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from drivers.modbus_codec import decode  # noqa: E402
from drivers.sim.modbus_server import OUTPUTS, ModbusSimController  # noqa: E402
from models import tomltext  # noqa: E402

FAULTS = ("open_sensor", "spike", "stuck", "controller_restart", "link_loss", "write_reject")
SLEW_UM_S = 1.0
PERIOD_S = 1.0


def _proc_status(pid: int) -> dict[str, int]:
    out: dict[str, int] = {}
    with open(f"/proc/{pid}/status", encoding="ascii") as f:
        for line in f:
            key, _, value = line.partition(":")
            if key in ("VmRSS", "Threads"):
                out[key] = int(value.split()[0])
    out["fds"] = len(os.listdir(f"/proc/{pid}/fd"))
    return out


def _config(work: Path, endpoint: str, speedup: float) -> Path:
    real_period_s = PERIOD_S / speedup
    doc: dict[str, Any] = {
        "machine": {"name": "soak", "period_s": PERIOD_S, "time_scale": speedup},
        "controller": {"protocol": "modbus", "endpoint": endpoint,
                       "timeout_s": round(0.4 * real_period_s, 6), "connect_timeout_s": 1.0,
                       "backoff": {"initial_s": min(0.05, real_period_s), "cap_s": 0.5}},
        "channels": {
            "bearing": {"address": {"kind": "input", "address": 0, "type": "int16",
                                    "scale": 0.1},
                        "unit": "degC", "range": [-20.0, 150.0], "max_rate_per_s": 1.0,
                        "stale_after_s": 10.0, "stuck_after_s": 300.0},
            "ambient": {"address": {"kind": "input", "address": 4, "type": "int16",
                                    "scale": 0.1},
                        "unit": "degC", "range": [-10.0, 60.0]}},
        "model": {"file": "sp2"},
        "output": {"offset": OUTPUTS["offset"].model_dump(),
                   "heartbeat": OUTPUTS["heartbeat"].model_dump(),
                   "status": OUTPUTS["status"].model_dump(),
                   "limit_um": 100.0, "slew_um_s": SLEW_UM_S},
        "faults": {"hold_s": 60.0, "shutdown": "hold"},
        "state": {"dir": str(work / "state"), "checkpoint_every": 60},
        "recorder": {"commit_every": 50},
        "telemetry": {"log_format": "json", "log_level": "warning"},
    }
    path = work / "compd.toml"
    path.write_text(tomltext.dumps(doc), encoding="utf-8")
    return path


class Soak:
    def __init__(self, hours: float, speedup: float, fault_every_min: float, seed: int) -> None:
        self.hours = hours
        self.speedup = speedup
        self.fault_every_s = fault_every_min * 60.0
        self.rng = random.Random(seed)
        self.sim = ModbusSimController()
        #: (monotonic s, offset the controller held before the write, offset written)
        self.writes: list[tuple[float, float, float]] = []
        self.faults: list[tuple[float, str]] = []
        self.stuck_until_s = -1.0
        self.open_until_s = -1.0
        self.spike_at_s = -1.0
        original = self.sim._action

        async def action(function_code: int, start: int, address: int, count: int,
                         registers: list[int], set_values: Any) -> Any:
            if set_values is not None and address == 0 and count >= 2:
                held = decode(OUTPUTS["offset"], self.sim.raw("holding", 0, 2))
                self.writes.append((time.monotonic(), held,
                                    decode(OUTPUTS["offset"], list(set_values[:2]))))
            return await original(function_code, start, address, count, registers,
                                  set_values)

        self.sim._action = action  # type: ignore[method-assign,assignment]  # watch writes

    def bearing_c(self, t_s: float) -> float:
        """A warm-up, then a 40-minute load cycle (machine seconds)."""
        return 20.0 + 6.0 * (1.0 - math.exp(-t_s / 1800.0)) + 2.0 * math.sin(t_s / 2400.0 * 6.28)

    async def plant(self, t0: float, stop: asyncio.Event) -> None:
        last = 20.0
        while not stop.is_set():
            t_s = (time.monotonic() - t0) * self.speedup
            if t_s < self.open_until_s:
                self.sim.set_raw("input", 0, [0x7FFF])  # an open Pt100
            elif abs(t_s - self.spike_at_s) < PERIOD_S:
                await self.sim.publish({"bearing": last + 50.0})
            elif t_s < self.stuck_until_s:
                pass  # the sensor repeats its last value
            else:
                last = round(self.bearing_c(t_s), 1)
                await self.sim.publish({"bearing": last, "ambient": 20.0})
            await asyncio.sleep(0.25 * PERIOD_S / self.speedup)

    async def fault(self, t_s: float) -> None:
        kind = self.rng.choice(FAULTS)
        self.faults.append((round(t_s, 1), kind))
        outage_real_s = 30.0 / self.speedup
        if kind == "open_sensor":
            self.open_until_s = t_s + 30.0
        elif kind == "spike":
            self.spike_at_s = t_s + PERIOD_S
        elif kind == "stuck":
            self.stuck_until_s = t_s + 600.0
        elif kind == "controller_restart":
            await self.sim.stop()
            await self.sim.forget_outputs()
            await self.sim.start()
        elif kind == "link_loss":
            await self.sim.stop()
            await asyncio.sleep(outage_real_s)
            await self.sim.start()
        elif kind == "write_reject":
            self.sim.inject_exception("holding", 0, 4, count=2, on="write")
            await asyncio.sleep(outage_real_s)
            self.sim.clear_faults()

    async def run(self) -> dict[str, Any]:
        await self.sim.start()
        await self.sim.publish({"bearing": 20.0, "ambient": 20.0})
        duration_real_s = self.hours * 3600.0 / self.speedup
        with tempfile.TemporaryDirectory(prefix="compd-soak-") as d:
            work = Path(d)
            config = _config(work, self.sim.endpoint, self.speedup)
            log = (work / "daemon.log").open("wb")
            env = {**os.environ, "PYTHONPATH": str(ROOT)}
            env.pop("NOTIFY_SOCKET", None)
            proc = await asyncio.create_subprocess_exec(
                sys.executable, "-m", "compd", "run", str(config), stdout=log, stderr=log,
                stdin=asyncio.subprocess.DEVNULL, env=env, cwd=str(ROOT))
            log.close()
            t0 = time.monotonic()
            stop = asyncio.Event()
            plant = asyncio.create_task(self.plant(t0, stop))
            samples: list[dict[str, float]] = []
            next_fault_s = self.fault_every_s
            try:
                while (elapsed := time.monotonic() - t0) < duration_real_s:
                    if proc.returncode is not None:
                        raise RuntimeError(f"compd run exited {proc.returncode}")
                    t_s = elapsed * self.speedup
                    if t_s >= next_fault_s:
                        await self.fault(t_s)
                        next_fault_s += self.fault_every_s
                    if not samples or elapsed - samples[-1]["real_s"] >= 2.0:
                        st = _proc_status(proc.pid)
                        samples.append({"real_s": elapsed, "machine_s": t_s,
                                        "rss_kb": st["VmRSS"], "threads": st["Threads"],
                                        "fds": st["fds"]})
                    await asyncio.sleep(0.05)
                proc.send_signal(signal.SIGTERM)
                rc = await asyncio.wait_for(proc.wait(), 30.0)
            finally:
                stop.set()
                await plant
                if proc.returncode is None:
                    proc.kill()
                    await proc.wait()
                await self.sim.stop()
            log_tail = (work / "daemon.log").read_text(errors="replace")[-1500:]
        return self.report(samples, rc, log_tail)

    def report(self, samples: list[dict[str, float]], rc: int, log_tail: str) -> dict[str, Any]:
        warm = [s for s in samples if s["machine_s"] >= 0.1 * self.hours * 3600.0] or samples
        # what the machine sees: each write against what the controller held then
        # (after a restart that forgot the offset, that is 0, not our last write)
        steps = [(abs(u1 - held), (t1 - t0) * self.speedup)
                 for (t0, _, _), (t1, held, u1) in itertools.pairwise(self.writes)]
        max_step = max((s for s, _ in steps), default=0.0)
        # per machine second: a step over a gap of dt covers max(dt, Ts)
        max_rate = max((s / max(dt, PERIOD_S) for s, dt in steps), default=0.0)
        return {
            "machine_hours": self.hours, "speedup": self.speedup,
            "real_s": round(samples[-1]["real_s"], 1) if samples else 0.0,
            "faults": self.faults,
            "offset_writes": len(self.writes),
            "offset_range_um": [round(min(u for _, _, u in self.writes), 3),
                                round(max(u for _, _, u in self.writes), 3)]
            if self.writes else [],
            "max_step_um_per_write": round(max_step, 4),
            "max_du_um_per_machine_s": round(max_rate, 4),
            "slew_limit_um_s": SLEW_UM_S,
            "rss_kb_first": samples[0]["rss_kb"] if samples else None,
            "rss_kb_after_warmup": warm[0]["rss_kb"],
            "rss_kb_last": samples[-1]["rss_kb"],
            "rss_growth_mb_after_warmup": round((samples[-1]["rss_kb"] - warm[0]["rss_kb"])
                                                / 1024.0, 3),
            "fds_min_max": [min(s["fds"] for s in warm), max(s["fds"] for s in warm)],
            "threads_min_max": [min(s["threads"] for s in warm),
                                max(s["threads"] for s in warm)],
            "samples": len(samples),
            "exit_status": rc,
            "log_tail": log_tail if rc != 0 else "",
        }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=1.0, help="machine hours (default 1)")
    ap.add_argument("--speedup", type=float, default=30.0,
                    help="machine seconds per real second (default 30: 1 h in 2 min)")
    ap.add_argument("--fault-every-min", type=float, default=4.0,
                    help="machine minutes between faults (default 4)")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    report = asyncio.run(Soak(args.hours, args.speedup, args.fault_every_min, args.seed).run())
    print(json.dumps(report, indent=1))
    ok = (report["rss_growth_mb_after_warmup"] < 5.0 and report["exit_status"] == 0
          and report["max_step_um_per_write"] <= 2 * SLEW_UM_S * PERIOD_S + 1e-3)
    print(f"soak: {'PASS' if ok else 'FAIL'} (RSS growth < 5 MB, exit 0, no step above 2·R·Ts)")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
