"""`compd check CONFIG [--connect] [--json]` for a daemon config.

Validates the whole file and the model(s) and connects to nothing; with
``--connect`` it also reads each channel (and the outputs) once and prints
them. Any invalid configuration raises ConfigError (exit 78, one message
naming the key and the reason).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import sys
from pathlib import Path
from typing import Any

from compd.config.loader import LoadedConfig
from drivers.endpoint import redact_endpoint


def _summary(cfg: LoadedConfig) -> dict[str, Any]:
    from compd.core.output import count_warnings
    from compd.offline.model_description import describe_model

    raw = cfg.raw
    out: dict[str, Any] = {
        "config": str(cfg.path),
        "machine": raw.machine.name, "period_s": raw.machine.period_s,
        "time_scale": raw.machine.time_scale,
        "protocol": raw.controller.protocol,
        # a user name or password is refused by the config; hidden here all the same
        "endpoint": redact_endpoint(raw.controller.endpoint),
        "channels": {n: {"address": a.describe(), "unit": raw.channels[n].unit,
                         "range": list(raw.channels[n].range)}
                     for n, a in cfg.channels.items()},
        "outputs": {n: a.describe() for n, a in cfg.outputs.items()},
        "controller_state": {n: a.describe() for n, a in cfg.states.items()},
        "output": {"limit_um": raw.output.limit_um, "slew_um_s": raw.output.slew_um_s,
                   "deadband_um": raw.output.deadband_um, "sign": raw.output.sign,
                   "units_per_um": raw.output.units_per_um, "readback": raw.output.readback,
                   "count_um": cfg.offset_quantum_um or None},
        "warnings": count_warnings(quantum_um=cfg.offset_quantum_um,
                                   slew_um_s=raw.output.slew_um_s,
                                   period_s=raw.machine.period_s, limit_um=raw.output.limit_um)
        + _state_warnings(cfg) + _adaptation_warnings(cfg),
        "model": describe_model(cfg.model),
        "model_sha256": cfg.model_sha256,
        "recorder_only": cfg.recorder_only,
    }
    if cfg.recorder_only:  # no output stage: its figures are nobody's
        del out["output"]
        out["warnings"] = _state_warnings(cfg) + _adaptation_warnings(cfg)
        if not cfg.model_given:
            del out["model"], out["model_sha256"]
    if cfg.shadow is not None:
        out["shadow"] = describe_model(cfg.shadow)
    return out


def _state_warnings(cfg: LoadedConfig) -> list[str]:
    """LinuxCNC zeroes its external offset at machine on and ignores it while off or
    not homed: without output.machine_on and output.homed compd cannot tell, and
    fights it (refused writes, a write fault; a READBACK_MISMATCH alarm at each
    machine on)."""
    if cfg.raw.controller.protocol != "linuxcnc":
        return []
    out: list[str] = []
    if "homed" not in cfg.states:
        out.append("output.homed is not set: LinuxCNC takes no external offset before "
                   "the machine is homed; without it compd's writes are refused then (a "
                   "write fault): set homed = { kind = \"get\", hal = "
                   "\"motion.is-all-homed\" } (docs/protocols.md §10)")
    if "machine_on" not in cfg.states:
        out.append("output.machine_on is not set: LinuxCNC takes no external offset while "
                   "the machine is off and zeroes it at machine on; without it compd's "
                   "writes are refused while off (a write fault) and the zeroed offset "
                   "reads as foreign (READBACK_MISMATCH): set machine_on = { kind = "
                   "\"get\", hal = \"motion.motion-enabled\" } (docs/protocols.md §10)")
    return out


def _adaptation_warnings(cfg: LoadedConfig) -> list[str]:
    """Adaptation applied with settings not learnt for the model (its file has no
    [adaptation] table with the score's prior: fitted before `compd fit` learnt them,
    or a bundled model): the library's defaults, which made a real machine worse than
    the plain model; the estimator starts stood down (`models.adaptation`)."""
    a = cfg.adaptation
    if a is None or a.mode != "apply" or not a.params.unproven:
        return []
    why = cfg.model.provenance.get("adaptation_not_learnt")
    said = f" (compd fit did not learn them: {why})" if isinstance(why, str) else ""
    return [f"adaptation.mode = \"apply\" with model {cfg.model.name!r}, whose file carries "
            f"no [adaptation] settings learnt for it{said}: the library's defaults lag a real "
            "machine's drift (on the real record of docs/adaptation.md §6 they made it worse "
            "than the plain model: RMS 7.17 against 6.26 µm); the estimator starts stood "
            "down and applies nothing until its probes show adapting pays. Refit the model "
            "(compd fit --adaptation learns them) or refine them from the machine's probes "
            "(compd refine)"]


async def _read_once(cfg: LoadedConfig) -> dict[str, Any]:
    from compd.runtime.driver_setup import build_driver
    from drivers.errors import DriverError

    driver = build_driver(cfg)
    try:
        await asyncio.wait_for(driver.connect(), cfg.raw.controller.connect_timeout_s)
        got = await driver.read([*cfg.channels, *cfg.outputs, *cfg.states])
    except (DriverError, TimeoutError) as exc:
        return {"error": f"{type(exc).__name__}: {exc}"}
    finally:
        await driver.close()
    return {n: {"value": s.value if math.isfinite(s.value) else None,
                "quality": s.quality.value, "timestamp_s": s.timestamp_s}
            for n, s in got.items()}


def run(args: argparse.Namespace) -> int:
    from compd.config.loader import load_config

    return report(load_config(args.path), args)


def report_directory(directory: Path, args: argparse.Namespace) -> int:
    """`compd check DIR`: what `compd run DIR` validates before it connects (every
    *.toml, one machine each, no two sharing a name or state directory, each
    driver constructed), then each machine's report; --json: one object with a
    ``machines`` list. The status is the worst of the machines'."""
    from compd.runtime.fleet import build_drivers, load_machines

    configs = load_machines(directory)  # ConfigError (naming each bad file) -> 78
    for driver in build_drivers(configs).values():
        asyncio.run(driver.close())
    if not args.json:
        print(f"directory {directory}: {len(configs)} machine(s)")
        return max(report(cfg, args) for cfg in configs)
    machines: list[dict[str, Any]] = []
    rc = 0
    for cfg in configs:
        doc = _summary(cfg)
        for warning in doc["warnings"]:
            print(f"compd check: {cfg.path}: warning: {warning}", file=sys.stderr)
        if getattr(args, "connect", False):
            doc["read"] = asyncio.run(_read_once(cfg))
            rc = max(rc, 1 if "error" in doc["read"] else 0)
        machines.append(doc)
    print(json.dumps({"directory": str(directory), "machines": machines}))
    return rc


def report(cfg: LoadedConfig, args: argparse.Namespace) -> int:
    """Print what `compd check` says of a loaded config (and read it with --connect)."""
    from compd.runtime.driver_setup import check_driver

    check_driver(cfg)  # run's own pre-connect refusals (a missing FOCAS library…): 78
    report = _summary(cfg)
    for warning in report["warnings"]:
        print(f"compd check: warning: {warning}", file=sys.stderr)
    rc = 0
    if getattr(args, "connect", False):
        values = asyncio.run(_read_once(cfg))
        report["read"] = values
        rc = 1 if "error" in values else 0
    if args.json:
        print(json.dumps(report))
        return rc
    print(f"config {report['config']}: OK")
    print(f"  machine {report['machine']!r}, period {report['period_s']} s, "
          f"time scale {report['time_scale']}")
    print(f"  controller {report['protocol']} at {report['endpoint']}")
    for name, ch in report["channels"].items():
        print(f"  channel {name}: {ch['address']} [{ch['unit']}] range {ch['range']}")
    for name, addr in report["outputs"].items():
        print(f"  output {name}: {addr}")
    for name, addr in report.get("controller_state", {}).items():
        print(f"  controller state {name}: {addr} (no offset written while "
              f"{'set' if name == 'estop' else 'clear'})")
    if report["recorder_only"]:
        print("  recorder only ([output] enabled = false): reads, validates and records; "
              "writes nothing to the controller (no offset, heartbeat or status)")
        if "model" in report:
            m = report["model"]
            print(f"  model {m['model']!r}: evaluated and recorded, never written")
        _print_read(report)
        return rc
    o = report["output"]
    print(f"  output stage: limit ±{o['limit_um']} µm, slew {o['slew_um_s']} µm/s, "
          f"deadband {o['deadband_um']} µm, sign {o['sign']:+d}, "
          f"{o['units_per_um']} units/µm, read-back {'on' if o['readback'] else 'off'}"
          + (f", one count {o['count_um']:g} µm" if o["count_um"] else ""))
    m = report["model"]
    print(f"  model {m['model']!r}: {len(m['terms'])} term(s), all stable "
          f"({', '.join(t['name'] + ' DC ' + format(t['dc_gain'], '.4g') for t in m['terms'])})")
    from compd.offline.model_description import fallback_lines

    for line in fallback_lines(m.get("fallbacks", {})):
        print(f"  {line}")
    if "shadow" in report:
        print(f"  shadow model {report['shadow']['model']!r} (evaluated, never written)")
    _print_read(report)
    return rc


def _print_read(report: dict[str, Any]) -> None:
    if "read" in report:
        if "error" in report["read"]:
            print(f"  connect: FAILED {report['read']['error']}")
        for name, v in report["read"].items():
            if name != "error":
                print(f"  read {name} = {v['value']} ({v['quality']})")
