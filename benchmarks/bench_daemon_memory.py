"""Resident memory of `compd run` over one hour of machine time, per protocol.

For each protocol, a `compd sim --protocol P --speedup X` process serves the
simulated machine and a `compd run CONFIG` process (recorder on, checkpoint
every 60, JSON logs at info to a file) runs against it at the same
machine.time_scale X = 3600 / --wall-s, so one machine hour (3600 cycles at
1 s) takes --wall-s real seconds. VmRSS of the daemon (/proc/PID/status) is
sampled --samples times over the run.

Printed per protocol: RSS at the first complete cycle ("ready" in its log),
at the end, growth, the least-squares slope over the whole run and over its
second half (MB per machine hour), the peak, and the target (60 MB for S7 and
Modbus, 90 MB for OPC UA). The peer, measured in the same run: a bare Python
process importing the protocol's driver library (and numpy, which the models
use) and nothing of compd, so the daemon's own share is RSS - that baseline.

Then which heavy modules `compd run` holds: the packages whose shared
objects the running daemon mapped (/proc/PID/maps), and a probe that runs
``compd run --once`` in-process and lists the top-level packages in
sys.modules (scipy, matplotlib and another protocol's driver library must not
be there).

Run:  .venv/bin/python benchmarks/bench_daemon_memory.py [--protocols modbus s7 opcua]
      [--wall-s 60] [--samples 60]   (about 1 minute per protocol with the defaults)
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from daemon_bench_common import config_doc, rss_mb, start_sim, write_config

TARGET_MB = {"modbus": 60.0, "s7": 60.0, "opcua": 90.0, "focas": 60.0}
LIBRARY = {"modbus": "pymodbus", "s7": "snap7", "opcua": "asyncua", "focas": "ctypes"}
#: packages worth naming when present (heavy, or a library of another protocol)
HEAVY = ("numpy", "scipy", "matplotlib", "pandas", "asyncua", "snap7", "pymodbus",
         "cryptography", "pydantic", "pydantic_core", "prometheus_client", "structlog",
         "rich", "pygments", "sqlite3", "ssl", "aiofiles", "wait_for2", "sortedcontainers",
         "aiosqlite", "PIL", "hypothesis")
FORBIDDEN = ("scipy", "matplotlib")


@dataclass
class Run:
    protocol: str
    times_s: list[float]
    rss: list[float]
    ready_mb: float
    baseline_mb: float
    maps: list[str]
    modules: list[str]
    cycles_log: str

    def slope(self, first: float = 0.0) -> float:
        """Least-squares RSS slope, MB per machine hour, from fraction `first` of the run."""
        n0 = int(len(self.times_s) * first)
        t, y = self.times_s[n0:], self.rss[n0:]
        if len(t) < 3:
            return float("nan")
        tm, ym = sum(t) / len(t), sum(y) / len(y)
        den = sum((a - tm) ** 2 for a in t)
        per_s = sum((a - tm) * (b - ym) for a, b in zip(t, y, strict=True)) / den
        return per_s * 3600.0  # t is machine seconds


def _wait_ready(log: Path, proc: subprocess.Popen[bytes], limit_s: float = 30.0) -> None:
    end = time.monotonic() + limit_s
    while time.monotonic() < end:
        if proc.poll() is not None:
            raise RuntimeError(f"compd run exited {proc.returncode}: "
                               f"{log.read_text(errors='replace')[-1500:]}")
        if '"event": "ready"' in log.read_text(errors="replace"):
            return
        time.sleep(0.05)
    raise RuntimeError("compd run did not report ready")


def mapped_packages(pid: int) -> list[str]:
    """Top-level packages of site-packages (and lib-dynload) whose .so files `pid` mapped."""
    try:
        text = Path(f"/proc/{pid}/maps").read_text()
    except OSError:
        return []
    found: set[str] = set()
    for line in text.splitlines():
        m = re.search(r"site-packages/([^/]+)/", line)
        if m:
            found.add(m.group(1).split(".")[0])
        m = re.search(r"lib-dynload/(_?[a-z0-9]+)", line)
        if m:
            found.add(m.group(1))
    return sorted(found)


_PROBE = """
import json, sys
from compd.cli import main
rc = main(["run", sys.argv[1], "--once"])
print(json.dumps({"rc": rc, "modules": sorted({m.split(".")[0] for m in sys.modules})}))
"""

_BASELINE = """
import sys, time, importlib
for name in sys.argv[1:]:
    importlib.import_module(name)
print("ok", flush=True)
time.sleep(60)
"""


def baseline_rss(protocol: str) -> float:
    lib = {"modbus": "pymodbus.client", "s7": "snap7.client", "opcua": "asyncua.client",
           "focas": "ctypes"}[protocol]
    proc = subprocess.Popen([sys.executable, "-c", _BASELINE, lib, "numpy"],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    try:
        if proc.stdout is not None:
            proc.stdout.readline()
        return rss_mb(proc.pid)
    finally:
        proc.kill()
        proc.wait()


def measure(protocol: str, wall_s: float, samples: int, work: Path,
            hours: float = 1.0) -> Run:
    scale = 3600.0 / wall_s
    sim = start_sim(protocol, speedup=scale)
    log = work / f"{protocol}.log"
    try:
        doc = config_doc(sim.desc, state_dir=work / f"state-{protocol}", time_scale=scale)
        cfg = write_config(doc, work / f"{protocol}.toml")
        with log.open("wb") as out:
            proc = subprocess.Popen([sys.executable, "-m", "compd", "run", str(cfg)],
                                    stdin=subprocess.DEVNULL, stdout=out, stderr=out,
                                    env={"NOTIFY_SOCKET": "", **_env()})
        try:
            _wait_ready(log, proc)
            t0 = time.monotonic()
            ready = rss_mb(proc.pid)
            times, rss = [0.0], [ready]
            for k in range(1, samples + 1):
                time.sleep(max(0.0, t0 + k * hours * wall_s / samples - time.monotonic()))
                times.append((time.monotonic() - t0) * scale)
                rss.append(rss_mb(proc.pid))
            maps = mapped_packages(proc.pid)
        finally:
            proc.terminate()
            proc.wait(30)
        probe_doc = config_doc(sim.desc, state_dir=work / f"probe-{protocol}",
                               time_scale=scale)
        probe_cfg = write_config(probe_doc, work / f"probe-{protocol}.toml")
        out_probe = subprocess.run([sys.executable, "-c", _PROBE, str(probe_cfg)],
                                   check=True, capture_output=True, text=True,
                                   timeout=120, env={"NOTIFY_SOCKET": "", **_env()})
        probe = json.loads(out_probe.stdout.strip().splitlines()[-1])
    finally:
        sim.stop()
    stopped = [ln for ln in log.read_text(errors="replace").splitlines()
               if "daemon_stopped" in ln]
    return Run(protocol=protocol, times_s=times, rss=rss, ready_mb=ready,
               baseline_mb=baseline_rss(protocol), maps=maps, modules=probe["modules"],
               cycles_log=stopped[-1] if stopped else "(no daemon_stopped line)")


def _env() -> dict[str, str]:
    return dict(os.environ)


def report(runs: list[Run]) -> None:
    hours = max((r.times_s[-1] for r in runs), default=0.0) / 3600.0
    print(f"\n`compd run` resident memory over {hours:.1f} machine hour(s) (MB = 1e6 bytes)")
    print(f"{'protocol':9s}{'ready':>8s}{'end':>8s}{'growth':>8s}{'peak':>8s}"
          f"{'slope':>8s}{'slope 2nd half':>15s}{'target':>8s}{'baseline':>9s}{'own':>7s}")
    for r in runs:
        end = r.rss[-1]
        ok = "ok" if max(r.rss) < TARGET_MB[r.protocol] else "OVER"
        print(f"{r.protocol:9s}{r.ready_mb:8.1f}{end:8.1f}{end - r.ready_mb:+8.1f}"
              f"{max(r.rss):8.1f}{r.slope():+8.2f}{r.slope(0.5):+15.2f}"
              f"{TARGET_MB[r.protocol]:6.0f} {ok:4s}{r.baseline_mb:6.1f}"
              f"{end - r.baseline_mb:7.1f}")
    print("slope: MB per machine hour (least squares over the samples); baseline: a bare "
          "python importing the protocol's library + numpy; own = end - baseline")
    for r in runs:
        print(f"\n{r.protocol}: {r.cycles_log}")
        every = max(1, len(r.rss) // 12)
        print(f"  RSS samples (MB): {' '.join(f'{x:.1f}' for x in r.rss[::every])}")
        heavy = [m for m in HEAVY if m in r.modules]
        print(f"  heavy packages in sys.modules after `compd run --once`: {', '.join(heavy)}")
        others = sorted(set(LIBRARY.values()) - {LIBRARY[r.protocol], "ctypes"})
        bad = [m for m in (*FORBIDDEN, *others) if m in r.modules]
        print(f"  forbidden (scipy, matplotlib, {', '.join(others)}): "
              f"{', '.join(bad) if bad else 'none loaded'}")
        print(f"  packages with shared objects mapped in the daemon: {', '.join(r.maps)}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--protocols", nargs="+", default=["modbus", "s7", "opcua"],
                        choices=["modbus", "s7", "opcua", "focas"])
    parser.add_argument("--wall-s", type=float, default=60.0,
                        help="real seconds for one machine hour (time_scale = 3600 / this)")
    parser.add_argument("--samples", type=int, default=60)
    parser.add_argument("--hours", type=float, default=1.0,
                        help="machine hours to run (a longer run shows whether RSS levels off)")
    args = parser.parse_args()
    runs = []
    with tempfile.TemporaryDirectory(prefix="bench-daemon-memory-") as tmp:
        for protocol in args.protocols:
            run = measure(protocol, args.wall_s, args.samples, Path(tmp), args.hours)
            print(f"  {protocol}: ready {run.ready_mb:.1f} MB, end {run.rss[-1]:.1f} MB",
                  flush=True)
            runs.append(run)
    report(runs)


if __name__ == "__main__":
    main()
