"""`compd run CONFIG [--dry-run] [--once]`: the compensation daemon.

`compd run DIR`: every ``*.toml`` in DIR, each machine its own failure domain
(`compd.runtime.fleet`), spread over ``--workers N`` processes (default: the
cores; `compd.runtime.workers`; ``--workers 1``: all in this one process); 78
when any file is bad (naming it), 0 after SIGTERM.

Exit status: 0 after SIGTERM/SIGINT (checkpoint written, shutdown policy
applied), 78 on an invalid configuration (systemd does not restart it),
75 (EX_TEMPFAIL) when another daemon holds the state directory, 73
(EX_CANTCREAT) when the state directory cannot be used safely (not a
directory, another owner's, writable by others, a link planted in it), 78 when
a directory on its way lets another user swap it (owned by neither root nor
this user, or writable by group or others without the sticky bit), and with
``--once`` 0 when the one cycle was complete and valid, 1 when it was not.
"""

from __future__ import annotations

import argparse
import asyncio
import sys

from compd.argtypes import count
from compd.sysexits import EX_TEMPFAIL, EX_USAGE

HELP = "run the compensation daemon against the configured controller"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("config", metavar="CONFIG",
                        help="daemon config file (TOML), or a directory: every *.toml "
                             "in it, one machine each (see --workers)")
    parser.add_argument("--dry-run", action="store_true",
                        help="compute and log, write nothing to the controller or the state")
    parser.add_argument("--once", action="store_true",
                        help="run one cycle, print it as JSON and exit")
    parser.add_argument("--workers", metavar="N", type=count(1, 1024), default=None,
                        help="with a directory: spread its machines over N worker "
                             "processes, each restarted alone (default: the cores; 1: "
                             "every machine in this one process)")


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    if Path(args.config).is_dir():
        return run_directory(args)
    if args.workers is not None:
        print("compd run: --workers takes a directory of machine configs, not one file",
              file=sys.stderr)
        return EX_USAGE
    from compd.config.loader import load_config

    cfg = load_config(args.config)  # ConfigError -> 78 in compd.cli
    from compd.faces.telemetry import configure_logging
    from compd.runtime.daemon import Daemon
    from compd.runtime.statedir import StateDirError
    from compd.runtime.statelock import StateLocked

    tel = cfg.raw.telemetry
    configure_logging(json=None if tel.log_format == "auto" else tel.log_format == "json",
                      level=tel.log_level, library_level=tel.library_log_level)
    from compd.runtime.driver_setup import build_driver

    # constructed (not connected) before anything else: a refusal is a config error (78)
    daemon = Daemon(cfg, dry_run=args.dry_run, once=args.once, driver=build_driver(cfg))
    try:
        rc = asyncio.run(daemon.run())
    except StateLocked as exc:
        print(f"compd: {exc}", file=sys.stderr)
        return EX_TEMPFAIL
    except StateDirError as exc:  # 73, or 78 for a parent another user could swap
        print(f"compd: state directory refused: {exc}", file=sys.stderr)
        return exc.code
    if args.once and daemon.loop.last_result is not None:
        import json

        r = daemon.loop.last_result
        print(json.dumps({"sequence": r.sequence, "state": r.state, "complete": r.in_force,
                          "inputs_valid": r.inputs_valid, "offset_um": r.stage_um,
                          "confirmed_um": r.confirmed_um, "model_um": r.model_um,
                          "shadow_um": r.shadow_um, "status": r.status,
                          "writes": {} if args.dry_run else dict(r.writes),
                          "channels": dict(r.channels), "validity": dict(r.validity)}))
    return rc


def run_directory(args: argparse.Namespace) -> int:
    """`compd run DIR`: every *.toml in DIR, one machine each, in this one process
    (compd.runtime.fleet) or over --workers processes (compd.runtime.workers). A
    bad file refuses the whole start (78, naming it)."""
    from pathlib import Path

    from compd.runtime.fleet import Fleet, build_drivers, load_machines

    if args.once:
        print("compd run: --once takes one config file, not a directory", file=sys.stderr)
        return EX_USAGE
    configs = load_machines(Path(args.config))  # ConfigError -> 78 in compd.cli
    from compd.faces.telemetry import configure_logging

    tel = configs[0].raw.telemetry
    as_json = None if tel.log_format == "auto" else tel.log_format == "json"
    configure_logging(json=as_json, level=tel.log_level, library_level=tel.library_log_level)
    log = {"json": as_json, "level": tel.log_level, "library_level": tel.library_log_level}
    drivers = build_drivers(configs)  # constructed, so checked: a refusal is 78
    if args.workers != 1:
        from compd.runtime.workers import WorkerPool, default_workers

        workers = min(args.workers or default_workers(), len(configs))
        if workers > 1:
            del drivers  # each worker builds its own machines' drivers
            pool = WorkerPool(configs, workers, dry_run=args.dry_run, log_settings=log)
            return asyncio.run(pool.run())
    # --workers 1, or one machine, or one core: every machine in this process
    fleet = Fleet(configs, dry_run=args.dry_run, drivers=drivers)
    return asyncio.run(fleet.run())
