"""`compd sim --drive URL`: the simulated machine as a client of a real controller.

The HIL bench's machine side (`drivers.sim.drive`): the thermal plant writes
its sensors into the controller addresses of a drive map (``--map``, default
the one shipped for the protocol, ``drivers/sim/maps/<protocol>.toml``, which
the repository's ``deploy/hil/maps`` points to) and reads back the offset the
daemon wrote there. Runs until SIGINT/SIGTERM or ``--duration-h`` of machine time
(exit 0), printing one status line every ``--print-every-s`` real seconds;
``--record CSV`` writes the run (a calibration record plus offset, error,
heartbeat, status and link state) on the way out.

Exit codes: 0 done, 64 usage (bad endpoint, options that do not apply), 66
a drive map that cannot be read, 78 a drive map that cannot be used, 73/74 a
--record that cannot be written (checked before the session starts), 1 the
controller refused a write for good (the map does not fit the controller).
"""

from __future__ import annotations

import argparse
import asyncio
import math
import signal
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from drivers.sim.drive import DriveLoop

from compd.argtypes import number
from compd.config.urls import redact_urls
from compd.sysexits import EX_CONFIG, EX_USAGE


def add_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("HIL bench (--drive)")
    group.add_argument("--drive", metavar="URL", default=None,
                       help="drive a controller as the machine would: opcua://HOST:PORT, "
                            "s7://HOST:PORT, modbus://HOST:PORT or focas://HOST:PORT")
    group.add_argument("--map", metavar="TOML", default=None,
                       help="drive map: which addresses the plant writes and reads "
                            "(default: the one shipped for the protocol, as in "
                            "deploy/hil/maps/)")
    group.add_argument("--duration-h", type=number(0.0, 8784.0, lo_open=True), default=None,
                       help="stop after this much machine time, hours (default: run until "
                            "SIGINT/SIGTERM)")
    group.add_argument("--focas-library", metavar="PATH", default=None,
                       help="absolute path of the FOCAS library (overrides the map's "
                            "driver.library_path)")
    group.add_argument("--print-every-s", type=number(0.0, 86400.0), default=5.0,
                       help="real seconds between status lines (0: none; default 5)")


def _usage(message: str) -> int:
    print(f"compd sim: {redact_urls(message)}", file=sys.stderr)
    return EX_USAGE


def _status_line(drive: DriveLoop) -> str:
    row = drive.latest
    if not row:
        return "compd sim: (no exchange yet)"

    def num(name: str, fmt: str) -> str:
        value = row.get(name, math.nan)
        return "-" if math.isnan(value) else format(value, fmt)

    # the URL was checked (no user name or password); hidden here all the same
    link = "up" if row.get("link_ok") else f"DOWN ({redact_urls(str(drive.last_error))})"
    return (f"t={row['time_s'] / 3600:.3f} h speed={num('spindle_rpm', '.0f')} rpm "
            f"bearing={num('bearing', '.1f')} C growth={num('growth_um', '.2f')} um "
            f"offset={num('offset_um', '.2f')} um error={num('error_um', '.2f')} um "
            f"heartbeat={num('heartbeat', '.0f')} status={num('status', '.0f')} link={link}")


async def _printer(drive: DriveLoop, every_s: float) -> None:
    while True:
        await asyncio.sleep(every_s)
        print(_status_line(drive), flush=True)


async def _drive(args: argparse.Namespace, drive: DriveLoop, until_s: float | None) -> int:
    from drivers.errors import DriverError

    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    signals = (signal.SIGINT, signal.SIGTERM)
    for sig in signals:
        loop.add_signal_handler(sig, stop.set)
    rc = 0
    try:
        task = drive.start(until_s=until_s)
        waiter = asyncio.create_task(stop.wait(), name="sim-drive-signal")
        helpers: set[asyncio.Task[Any]] = {waiter}
        if args.print_every_s > 0:
            helpers.add(asyncio.create_task(_printer(drive, args.print_every_s),
                                            name="sim-drive-printer"))
        await asyncio.wait({task, waiter}, return_when=asyncio.FIRST_COMPLETED)
        for helper in helpers:
            helper.cancel()
        await asyncio.gather(*helpers, return_exceptions=True)
        try:
            await drive.stop()
        except DriverError as exc:  # a permanent refusal: the map does not fit
            print(f"compd sim: the controller refused: {redact_urls(str(exc))}", file=sys.stderr)
            rc = 1
    finally:
        for sig in signals:
            loop.remove_signal_handler(sig)
        await drive.stop()  # a no-op once stopped above
    return rc


def run_drive(args: argparse.Namespace) -> int:
    from compd.infiles import read_toml
    from compd.outfiles import check_output, write_atomically
    from drivers.sim.drive import DriveLoop, drive_endpoint, open_drive_driver, write_drive_record
    from drivers.sim.drive_map import MAPS_DIR, DriveMapError, parse_drive_map
    from drivers.sim.programs import make_program

    if args.protocol is not None:
        return _usage("--drive runs against a controller; drop --protocol")
    if args.json or args.port:
        return _usage("--json and --port serve a simulated controller; they do not "
                      "apply to --drive")
    if args.duration_h is not None and not (args.duration_h > 0 and math.isfinite(
            args.duration_h)):
        return _usage("--duration-h must be a positive number")
    if not (args.print_every_s >= 0 and math.isfinite(args.print_every_s)):
        return _usage("--print-every-s must be >= 0")
    try:  # the checks of the daemon's [controller] endpoint: no user name or password
        protocol, endpoint = drive_endpoint(args.drive)
    except ValueError as exc:
        return _usage(str(exc))
    map_path = Path(args.map) if args.map else MAPS_DIR / f"{protocol}.toml"
    if args.map is None and not map_path.is_file():
        return _usage(f"no default map at {map_path}; give --map FILE.toml")
    if args.record is not None:  # before the session: a record lost at the end is no record
        check_output(args.record, "record", force=args.force, inputs=[map_path])
    try:
        drive_map = parse_drive_map(read_toml(map_path, "drive map"), str(map_path))
    except DriveMapError as exc:
        print(f"compd sim: bad drive map: {exc}", file=sys.stderr)
        return EX_CONFIG
    overrides: dict[str, Any] = {}
    if args.focas_library is not None:
        if protocol != "focas":
            return _usage("--focas-library applies to focas:// only")
        overrides["library_path"] = args.focas_library
    try:
        driver = open_drive_driver(args.drive, drive_map, **overrides)
    except (ValueError, TypeError) as exc:  # protocol mismatch, library refused, ...
        print(f"compd sim: cannot use {endpoint} with {map_path}: {redact_urls(str(exc))}",
              file=sys.stderr)
        return EX_CONFIG
    program = make_program(args.program, seed=args.seed, hours=args.hours)
    drive = DriveLoop(driver, drive_map, program=program, seed=args.seed,
                      period_s=args.period_s, speedup=args.speedup,
                      record=args.record is not None)
    until_s = args.duration_h * 3600.0 if args.duration_h is not None else None
    print(f"compd sim: driving {endpoint} ({protocol}) with {map_path}: program "
          f"{program.name}, speedup {args.speedup:g}, period {args.period_s:g} s, "
          f"seed {args.seed}", flush=True)
    rc = asyncio.run(_drive(args, drive, until_s))
    if args.record is not None:
        history, written = drive.history_arrays(), [0]
        write_atomically(args.record,
                         lambda tmp: written.append(write_drive_record(tmp, history)), "record",
                         force=args.force, inputs=[map_path])
        rows = written[-1]
        print(f"compd sim: wrote {rows} rows to {args.record}")
    print(_status_line(drive))
    print(f"compd sim: stopped after {drive.time_s / 3600:.3f} h of machine time, "
          f"{drive.ticks} tick(s), {drive.overruns} overrun(s), "
          f"{drive.link_errors} link error(s)", flush=True)
    return rc
