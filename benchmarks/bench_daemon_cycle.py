"""The daemon's own cost per cycle against the driver's bare round trip.

For each protocol and rate (1, 10, 100 Hz), against one simulated machine
served by a separate `compd sim --protocol P --speedup RATE` process:

- daemon: the real `compd.runtime.daemon.Daemon` (recorder on, checkpoint every 60,
  JSON logs at info to a file, metrics objects live) runs in this process with
  timing hooks *around* it (`daemon_bench_common.TimedDriver` and
  `TimedDaemon`; the daemon's code is unchanged). Its own cost per cycle =
  cycle time - time inside the driver calls + checkpoint time amortised;
  split into step (validation, model, fault policy, output stage, events),
  record, telemetry (metrics, log calls, sd_notify) and checkpoint;
- peer, measured in the same run against the same simulated controller: the
  same driver class on its own, at the same rate on absolute deadlines, doing
  the daemon's I/O by hand: read the channels and the offset read-back in one
  call, write offset + heartbeat + status in one call.

Ratio printed: daemon own cost / bare round trip (median). Also the daemon's
lateness (cycle start - deadline) and overruns.

Run:  .venv/bin/python benchmarks/bench_daemon_cycle.py [--protocols modbus opcua s7]
      [--rates 1 10 100] [--seconds 8]
(each rate runs max(12 cycles, seconds·rate) cycles for the daemon and for the peer
after a short warm-up; about 2 minutes with the defaults).
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from daemon_bench_common import (
    TimedDaemon,
    TimedDriver,
    config_doc,
    leaked_cancel,
    percentile,
    start_sim,
    write_config,
)

from compd.config.loader import LoadedConfig, load_config
from compd.faces.telemetry import configure_logging
from compd.runtime.driver_setup import build_driver
from drivers.errors import DriverError

WARMUP_CYCLES = 5


@dataclass
class Figures:
    protocol: str
    rate_hz: float
    cycles: int
    bare_med_ms: float
    bare_p99_ms: float
    io_med_ms: float
    own_med_ms: float
    own_p99_ms: float
    step_med_ms: float
    record_med_ms: float
    telemetry_med_ms: float
    checkpoint_amort_ms: float
    checkpoint_call_ms: float
    late_p50_ms: float
    late_p99_ms: float
    overruns: int
    writes: int
    bare_errors: int
    incomplete: int


async def _run_daemon(cfg: LoadedConfig, cycles: int) -> tuple[TimedDaemon, TimedDriver]:
    driver = TimedDriver(build_driver(cfg))
    daemon = TimedDaemon(cfg, driver=driver)
    daemon.stop_after = cycles + WARMUP_CYCLES
    rc = await daemon.run()
    if rc != 0:
        raise RuntimeError(f"daemon exited {rc}")
    return daemon, driver


async def _run_bare(cfg: LoadedConfig, cycles: int, errors: list[int],
                    leaked: list[int]) -> list[float]:
    driver = build_driver(cfg)
    names = [*cfg.channels, "offset"]
    period = cfg.real_period_s
    out: list[float] = []
    await driver.connect()
    try:
        deadline = time.monotonic()
        for k in range(cycles + WARMUP_CYCLES):
            t0 = time.perf_counter()
            try:
                got = await driver.read(names)
                await driver.write({"offset": got["offset"].value, "heartbeat": k % 65536,
                                    "status": 0})
            except DriverError:
                errors[0] += k >= WARMUP_CYCLES
            except asyncio.CancelledError as exc:
                if not leaked_cancel(exc):  # see daemon_bench_common.leaked_cancel
                    raise
                errors[0] += k >= WARMUP_CYCLES
                leaked[0] += 1
            else:
                if k >= WARMUP_CYCLES:
                    out.append(time.perf_counter() - t0)
            deadline += period
            await asyncio.sleep(max(0.0, deadline - time.monotonic()))
    finally:
        await driver.close()
    return out


def measure(protocol: str, rate_hz: float, seconds: float, work: Path) -> Figures:
    cycles = max(12, round(seconds * rate_hz))
    sim = start_sim(protocol, speedup=rate_hz)
    try:
        doc = config_doc(sim.desc, state_dir=work / f"{protocol}-{rate_hz:g}",
                         period_s=1.0, time_scale=rate_hz)
        cfg = load_config(write_config(doc, work / f"{protocol}-{rate_hz:g}.toml"))
        errors, leaked = [0], [0]
        bare = asyncio.run(_run_bare(cfg, cycles, errors, leaked))
        daemon, driver = asyncio.run(_run_daemon(cfg, cycles))
        leaked[0] += driver.leaked
        if leaked[0]:
            print(f"  NOTE {protocol} {rate_hz:g} Hz: {leaked[0]} driver call(s) (bare + daemon) "
                  "raised wait_for2.CancelledWithResultError, not a DriverError")
    finally:
        sim.stop()
    t = daemon.times
    w = WARMUP_CYCLES
    total, io = t.total[w:], t.io[w:]
    rec, tel = t.record[w:], t.telemetry[w:]
    # steady state: one checkpoint every state.checkpoint_every cycles
    ckpt_call_s = t.checkpoint_s / max(1, t.checkpoints)
    ckpt_amort = ckpt_call_s / cfg.raw.state.checkpoint_every
    own = [a - b + ckpt_amort for a, b in zip(total, io, strict=True)]
    step = [a - b - c - d for a, b, c, d in zip(total, io, rec, tel, strict=True)]
    late = t.lateness(cfg.real_period_s)[w:]
    ms = 1e3
    writes = len(daemon.loop.last_result.writes) if daemon.loop.last_result else 0
    return Figures(
        protocol=protocol, rate_hz=rate_hz, cycles=len(total),
        bare_med_ms=statistics.median(bare) * ms, bare_p99_ms=percentile(bare, 0.99) * ms,
        io_med_ms=statistics.median(io) * ms,
        own_med_ms=statistics.median(own) * ms, own_p99_ms=percentile(own, 0.99) * ms,
        step_med_ms=statistics.median(step) * ms, record_med_ms=statistics.median(rec) * ms,
        telemetry_med_ms=statistics.median(tel) * ms, checkpoint_amort_ms=ckpt_amort * ms,
        checkpoint_call_ms=ckpt_call_s * ms,
        late_p50_ms=percentile(late, 0.5) * ms, late_p99_ms=percentile(late, 0.99) * ms,
        overruns=daemon.loop.overruns, writes=writes, bare_errors=errors[0],
        incomplete=daemon.loop.cycles - daemon.telemetry.complete_cycles)


def report(rows: list[Figures]) -> None:
    print("\nDaemon own cost per cycle vs the driver's bare round trip "
          "(ms; one machine, sim in its own process)")
    head = (f"{'protocol':9s}{'Hz':>5s}{'cycles':>7s}{'bare med':>10s}{'bare p99':>10s}"
            f"{'daemon io':>10s}{'own med':>9s}{'own p99':>9s}{'own/bare':>9s}"
            f"{'late p50':>9s}{'late p99':>9s}{'overrun':>8s}")
    print(head)
    for r in rows:
        print(f"{r.protocol:9s}{r.rate_hz:5g}{r.cycles:7d}{r.bare_med_ms:10.3f}"
              f"{r.bare_p99_ms:10.3f}{r.io_med_ms:10.3f}{r.own_med_ms:9.3f}{r.own_p99_ms:9.3f}"
              f"{r.own_med_ms / r.bare_med_ms:8.2f}x{r.late_p50_ms:9.3f}{r.late_p99_ms:9.3f}"
              f"{r.overruns:8d}")
    print("\nown cost split (median ms per cycle; checkpoint = mean time per checkpoint / "
          "checkpoint_every (60), per call in brackets)")
    print(f"{'protocol':9s}{'Hz':>5s}{'step':>8s}{'record':>8s}{'telemetry':>10s}"
          f"{'checkpoint (call)':>21s}{'writes':>7s}{'incomplete':>11s}{'bare errors':>12s}")
    for r in rows:
        print(f"{r.protocol:9s}{r.rate_hz:5g}{r.step_med_ms:8.3f}{r.record_med_ms:8.3f}"
              f"{r.telemetry_med_ms:10.3f}{r.checkpoint_amort_ms:7.3f}"
              f" ({r.checkpoint_call_ms:5.2f}){r.writes:6d}"
              f"{r.incomplete:11d}{r.bare_errors:12d}")
    print("\nbare = same driver class, read channels + offset read-back, write offset + "
          "heartbeat + status;\nown = daemon cycle - its time inside the driver + checkpoint "
          "amortised; late = cycle start - deadline.")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--protocols", nargs="+", default=["modbus", "opcua", "s7"],
                        choices=["modbus", "opcua", "s7", "focas"])
    parser.add_argument("--rates", nargs="+", type=float, default=[1.0, 10.0, 100.0])
    parser.add_argument("--seconds", type=float, default=8.0,
                        help="measured seconds per rate and side (min 12 cycles)")
    args = parser.parse_args()
    rows: list[Figures] = []
    with tempfile.TemporaryDirectory(prefix="bench-daemon-cycle-") as tmp:
        work = Path(tmp)
        with (work / "daemon.log").open("w") as log:
            configure_logging(json=True, level="info", stream=log)
            for protocol in args.protocols:
                for rate in args.rates:
                    row = measure(protocol, rate, args.seconds, work)
                    print(f"  {protocol} {rate:g} Hz: own {row.own_med_ms:.3f} ms, "
                          f"bare {row.bare_med_ms:.3f} ms", flush=True)
                    rows.append(row)
    report(rows)


if __name__ == "__main__":
    main()
