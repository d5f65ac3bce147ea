"""`compd sim`: one simulated machine on 127.0.0.1, or an offline calibration record.

Serving: ``compd sim --protocol modbus [--port N] [--speedup X] [--program P]
[--seed N] [--json]`` starts the protocol's simulated controller, runs the
thermal plant behind it and serves until SIGINT/SIGTERM (exit 0). With
``--json`` the first stdout line is one JSON object
``{"protocol", "endpoint", "channels": {name: address}, "outputs": {...}}``,
plus, where the controller has them, ``"temp_comp"`` (per-axis compensation
parameters), ``"positions"`` and ``"axis_offsets"`` (each axis's present position
and a plain offset written at it) and ``"tool_comp"`` (the tool direction's value)
(addresses as the pydantic models of `drivers.addresses` dump them), so a bench
script can configure the daemon from it.

With ``--no-plant`` only the controller is served (no plant publishes into
it; OPC UA channel nodes are then client-writable): a stand-in PLC for trying
the HIL bench, where ``compd sim --drive URL`` (`compd.commands.sim_drive`)
plays the machine as a client of a controller and the daemon runs against the
same controller.

Offline: ``compd sim --record out.csv [--program P] [--hours H] [--period-s S]
[--seed N]`` writes a calibration record (see `drivers.sim.csvlog`) without
any server, faster than real time. ``--machine shop`` is the production
machine of `drivers.sim.shop`; ``--machine ballscrew [--positions 0,200,...]``
a ball-screw X axis whose record holds the displacement measured at each
position every row (`drivers.sim.ballscrew`; one row per 300 s unless
``--period-s``).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import signal
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from compd.argtypes import number, port, seed
from compd.commands import sim_drive, sim_record
from compd.sysexits import EX_TEMPFAIL, EX_USAGE
from drivers.protocols import NAMES

if TYPE_CHECKING:
    from drivers.sim.base import SimController
    from drivers.sim.shop import ShopChange

HELP = "serve one simulated machine on 127.0.0.1, or write a simulated calibration record"

#: from the protocol registry, which imports nothing heavy (the CLI parser stays light)
PROTOCOLS: tuple[str, ...] = NAMES
PROGRAMS: tuple[str, ...] = ("spectrum", "constant", "etve")
#: bounds of the numeric options: a tick of a millisecond to an hour, a
#: program of at most a year, a speed-up of at most a million
PERIOD_S = number(1e-3, 3600.0)
HOURS = number(0.0, 8784.0, lo_open=True)
SPEEDUP = number(0.0, 1e6, lo_open=True)
PROBE_NOISE_UM = number(0.0, 1000.0)
#: the measuring cycle: every minute of machine time to once a week
PROBE_EVERY_MIN = number(1.0, 7 * 24 * 60.0)
CHANGE_AT_H = number(0.0, 8784.0)
#: the farthest a --positions entry may lie from the axis's zero, mm, and the most
#: positions (each one more column of every row)
MAX_POSITION_MM = 100_000.0
MAX_POSITIONS = 100


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--protocol", choices=PROTOCOLS,
                        help="the controller to simulate (required unless --record)")
    parser.add_argument("--port", type=port, default=0,
                        help="TCP port on 127.0.0.1 (default: a free one)")
    parser.add_argument("--speedup", type=SPEEDUP, default=1.0,
                        help="machine seconds per real second (default 1)")
    parser.add_argument("--program", choices=PROGRAMS, default="spectrum",
                        help="spindle program (default spectrum; it repeats when served)")
    parser.add_argument("--hours", type=HOURS, default=None,
                        help="program duration in hours (default: the program's own)")
    parser.add_argument("--period-s", type=PERIOD_S, default=None,
                        help="machine seconds per tick / per record row (default 1; "
                             "300 with --machine ballscrew: one measuring pass a row)")
    parser.add_argument("--seed", type=seed, default=0, help="random seed (default 0)")
    parser.add_argument("--json", action="store_true",
                        help="print the endpoint and addresses as one JSON line first")
    parser.add_argument("--record", metavar="CSV", default=None,
                        help="write a calibration record offline instead of serving")
    parser.add_argument("--force", action="store_true",
                        help="replace an existing --record or --write-config file")
    parser.add_argument("--machine", choices=("bench", "shop", "ballscrew"), default="bench",
                        help="with --record: the bench machine (default), the shop variant "
                             "(16 sensors, starts warm, room drift; see drivers.sim.shop) or "
                             "a ball-screw X axis measured at several --positions (see "
                             "drivers.sim.ballscrew)")
    parser.add_argument("--positions", type=_positions, default=None, metavar="MM,MM,...",
                        help="with --machine ballscrew: the positions along the travel the "
                             "displacement is measured at, mm (default 0,200,400,600,800)")
    parser.add_argument("--change", type=_change, default=None, metavar="ambient±NK,heat±N%",
                        help="with --machine shop: a change the model never saw, e.g. "
                             "ambient+3K,heat+30%% (the room 3 K warmer, the spindle bearing's "
                             "losses 30 %% higher; see drivers.sim.shop.ShopChange)")
    parser.add_argument("--change-at-h", type=CHANGE_AT_H, default=0.0, metavar="H",
                        help="hour of the record the --change starts (default 0: from the "
                             "first row; 24 with --hours 48: calibrate on day 1, change on day 2)")
    parser.add_argument("--probe-noise-um", type=PROBE_NOISE_UM, default=0.5,
                        help="probe noise added to dz_um in --record, and to each "
                             "measurement of --probe-every-min (default 0.5 µm)")
    parser.add_argument("--probe-every-min", type=PROBE_EVERY_MIN, default=None,
                        metavar="MINUTES",
                        help="a measuring cycle every MINUTES machine minutes: the "
                             "controller's probe_value (growth - the offset in force + "
                             "noise, µm) and probe_counter (+1), for a daemon's [adaptation]")
    parser.add_argument("--write-config", metavar="TOML", default=None,
                        help="write the protocol's example config pointed at this server "
                             "(its port, --speedup as time_scale; FOCAS: the stand-in "
                             "library) before serving, for `compd run TOML`; replaces an "
                             "existing file only with --force")
    parser.add_argument("--no-plant", action="store_true",
                        help="serve the controller's memory only, no plant behind it (a "
                             "stand-in PLC for trying the HIL bench: --drive writes it)")
    sim_drive.add_arguments(parser)


def _change(text: str) -> ShopChange:
    """An argparse type: `drivers.sim.shop.parse_change` with its message on one line."""
    from drivers.sim.shop import parse_change

    try:
        return parse_change(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _positions(text: str) -> tuple[float, ...]:
    """An argparse type: two or more finite positions (mm), comma-separated, distinct
    to the 0.001 mm their column names hold."""
    items = text.split(",")
    if len(items) > MAX_POSITIONS:
        raise argparse.ArgumentTypeError(f"at most {MAX_POSITIONS} positions, got {len(items)}")
    try:
        out = tuple(float(item) for item in items)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected positions in mm like 0,200,400, got "
                                         f"{text!r}") from None
    if not all(abs(x) <= MAX_POSITION_MM for x in out):
        raise argparse.ArgumentTypeError(f"positions must be finite and within "
                                         f"±{MAX_POSITION_MM:g} mm, got {text!r}")
    if len({round(x, 3) for x in out}) != len(out) or len(out) < 2:  # one column each
        raise argparse.ArgumentTypeError(f"need two or more distinct positions (a line "
                                         f"along the travel), got {text!r}")
    return out


def describe(controller: SimController) -> dict[str, object]:
    """The JSON object `--json` prints."""
    doc: dict[str, object] = {
        "protocol": controller.protocol,
        "endpoint": controller.endpoint,
        "channels": {n: a.model_dump() for n, a in controller.channels.items()},
        "outputs": {n: a.model_dump() for n, a in controller.outputs_map.items()},
        "probes": {n: a.model_dump() for n, a in controller.probes.items()},
    }
    # per axis (docs/protocols.md §11): the temperature-compensation parameters, each
    # axis's position and plain offset (an offset written at the position read), the
    # tool direction's value (SINUMERIK), where the controller has them
    for key, attr in (("temp_comp", "temp_comp"), ("positions", "positions"),
                      ("axis_offsets", "axis_offsets"), ("tool_comp", "tool_comp")):
        table = getattr(controller, attr, None)
        if table:
            doc[key] = {n: a.model_dump() for n, a in table.items()}
    library = _library_path(controller)
    if library is not None:  # what a daemon config's [controller.focas] needs
        doc["focas"] = {"library_path": library}
    return doc


def _library_path(controller: SimController) -> str | None:
    """The FOCAS stand-in library the simulated CNC built (None for the others)."""
    path = getattr(controller, "library_path", None)
    return str(path) if path is not None else None


def _port_in_use(port: int) -> str:
    """Why 127.0.0.1:`port` cannot be served ("" when it can): asked before the
    protocol library tries, whose own failure is a traceback in its log."""
    import socket

    if port == 0:
        return ""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind(("127.0.0.1", port))
        except OSError as exc:
            return exc.strerror or str(exc)
    return ""


def _write_config(args: argparse.Namespace, controller: SimController,
                  rest_c: float | None) -> None:
    """The example config for this server, before the first line is printed: a
    reader waiting for that line finds the file written."""
    from compd.commands.sim_config import config_for
    from compd.outfiles import write_atomically

    command = f"compd sim --protocol {args.protocol} --speedup {args.speedup:g} " \
              f"--write-config {Path(args.write_config).name}"
    text = config_for(controller.protocol, controller.endpoint, args.speedup,
                      _library_path(controller), command, rest_c)
    write_atomically(args.write_config, lambda tmp: tmp.write_text(text, encoding="utf-8"),
                     "config", force=args.force)


async def _serve(args: argparse.Namespace) -> int:
    from drivers.sim.machine import SimMachine
    from drivers.sim.plant import ThermalPlant
    from drivers.sim.programs import make_program
    from drivers.sim.registry import make_sim_controller

    program = make_program(args.program, seed=args.seed, hours=args.hours)
    options = {"writable_channels": True} if args.no_plant and args.protocol == "opcua" else {}
    busy = _port_in_use(args.port)
    if busy:
        print(f"compd sim: cannot serve on 127.0.0.1:{args.port} ({busy})", file=sys.stderr)
        return EX_TEMPFAIL
    controller = make_sim_controller(args.protocol, "127.0.0.1", args.port, **options)
    await controller.start()
    if args.write_config is not None:
        try:
            # the plant SimMachine builds below: its rest state is the model's zero
            rest_c = None if args.no_plant else ThermalPlant(
                seed=args.seed, params=program.plant_params()).rest_c
            _write_config(args, controller, rest_c)
        except BaseException:
            await controller.stop()
            raise
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    signals = (signal.SIGINT, signal.SIGTERM)
    machine = SimMachine(controller, program=program, seed=args.seed,
                         period_s=args.period_s, speedup=args.speedup,
                         probe_every_s=(None if args.probe_every_min is None
                                        else 60.0 * args.probe_every_min),
                         probe_noise_um=args.probe_noise_um)
    for sig in signals:  # before anything is printed: a reader may signal at once
        loop.add_signal_handler(sig, stop.set)
    try:
        if not args.no_plant:
            await machine.prime()
        if args.json:
            print(json.dumps(describe(controller)), flush=True)
        else:
            print(f"compd sim: {controller.protocol} controller at {controller.endpoint}")
            if args.write_config is not None:
                print(f"  config for it in {args.write_config}: compd run {args.write_config}")
            library = _library_path(controller)
            if library is not None:
                print(f"  library_path {library}  (for [controller.focas] and --focas-library)")
            if args.no_plant:
                print("  no plant: the controller's memory only (for compd sim --drive)")
            else:
                print(f"  program {program.name} (repeats every "
                      f"{program.duration_s / 3600:g} h), speedup {args.speedup:g}, "
                      f"period {args.period_s:g} s, seed {args.seed}")
            tables = [("channels", controller.channels), ("outputs", controller.outputs_map)]
            if args.probe_every_min is not None:
                print(f"  measuring cycle every {args.probe_every_min:g} machine min, "
                      f"probe noise {args.probe_noise_um:g} µm")
                tables.append(("probes", controller.probes))
            for title, table in tables:
                print(f"  {title}:")
                for name, addr in table.items():
                    print(f"    {name:<10} {addr.describe()}")
            print("  Ctrl-C to stop", flush=True)
        waiter = asyncio.create_task(stop.wait(), name="sim-signal")
        running = {waiter} if args.no_plant else {machine.start(), waiter}
        await asyncio.wait(running, return_when=asyncio.FIRST_COMPLETED)
        waiter.cancel()
        await asyncio.gather(waiter, return_exceptions=True)
    finally:
        for sig in signals:
            loop.remove_signal_handler(sig)
        try:
            await machine.stop()
        finally:
            await controller.stop()
    if args.json:
        pass
    elif args.no_plant:
        print("compd sim: stopped")
    else:
        print(f"compd sim: stopped after {machine.time_s / 3600:.3f} h of machine time, "
              f"{machine.overruns} overrun(s)")
    return 0


def run(args: argparse.Namespace) -> int:
    if args.period_s is None:
        args.period_s = 300.0 if args.machine == "ballscrew" else 1.0
    if args.positions is not None and (args.record is None or args.machine != "ballscrew"):
        print("compd sim: --positions applies to --record with --machine ballscrew",
              file=sys.stderr)
        return EX_USAGE
    if args.drive is not None and args.probe_every_min is not None:
        print("compd sim: --probe-every-min applies to a served machine, not --drive",
              file=sys.stderr)
        return EX_USAGE
    if args.drive is not None and args.write_config is not None:
        print("compd sim: --write-config applies to a served machine, not --drive",
              file=sys.stderr)
        return EX_USAGE
    if args.drive is not None:
        return sim_drive.run_drive(args)
    if args.map is not None or args.duration_h is not None or args.focas_library is not None:
        print("compd sim: --map, --duration-h and --focas-library apply to --drive only",
              file=sys.stderr)
        return EX_USAGE
    if (args.change is not None or args.change_at_h) and (args.record is None
                                                         or args.machine != "shop"):
        print("compd sim: --change and --change-at-h apply to --record with --machine shop",
              file=sys.stderr)
        return EX_USAGE
    if args.change is None and args.change_at_h:
        print("compd sim: --change-at-h needs --change", file=sys.stderr)
        return EX_USAGE
    if args.probe_every_min is not None and (args.record is not None or args.no_plant):
        print("compd sim: --probe-every-min needs a plant to measure: not with --record "
              "or --no-plant", file=sys.stderr)
        return EX_USAGE
    if args.write_config is not None:
        if args.record is not None or args.protocol is None:
            print("compd sim: --write-config needs --protocol (a served machine), not --record",
                  file=sys.stderr)
            return EX_USAGE
        if args.protocol == "linuxcnc":
            print("compd sim: --write-config: the linuxcnc example runs against LinuxCNC "
                  "itself (docs/protocols.md), not a server of compd sim: start from "
                  "compd/examples/linuxcnc.toml (its commented X axis shows how to add "
                  "X and Y)", file=sys.stderr)
            return EX_USAGE
        from compd.outfiles import check_output

        check_output(args.write_config, "config", force=args.force)
    if args.record is not None:
        if args.protocol is not None:
            print("compd sim: --record runs offline; drop --protocol", file=sys.stderr)
            return EX_USAGE
        return sim_record.record(args)
    if args.protocol is None:
        print("compd sim: --protocol is required (or --record CSV for an offline record)",
              file=sys.stderr)
        return EX_USAGE
    return asyncio.run(_serve(args))
