"""A `compd plan` program run end to end in a real, headless LinuxCNC: what
benchmarks/bench_plan_linuxcnc.py prints and tests/compd/offline/plan/test_plan_linuxcnc.py
checks (the plan's figure in LinuxCNC).

1. ``compd plan --hours H --speeds 3000,6000,9000 --dialect linuxcnc
   --time-scale N`` writes the program (the speeds of benchmarks/bench_plan.py)
   with every dwell divided by N: LinuxCNC's ``G4 P`` dwells in real time, so
   the run is compressed by running everything else at N machine seconds per
   real second too (the plant's ticks, the daemon's ``[machine] time_scale``)
   and dividing the dwells.
2. LinuxCNC (`drivers.sim.linuxcnc_machine`, under its one-per-machine lock)
   runs the program; the simulated plant takes its spindle speed from
   ``spindle.0.speed-out`` each tick (`drivers.sim.linuxcnc_spindle`), so the
   program makes the heat, and publishes its temperatures and its true Z
   growth on HAL signals (``compd-<name>``, ``compd-growth_um``).
3. ``compd run`` (a real process) reads them as channels, the growth as
   ``dz_um``, with the ``[recorder]`` of the plan's ``warmup.recorder.toml``.
   It compensates LinuxCNC's Z as the example config says (its model):
   ``dz_um`` is the plant's own growth, which the offset does not change, so
   the record is the one an uncompensated run's sensors would give.
4. ``compd fit warmup.sqlite --column dz_um --term bearing --term motor --term
   column --term ambient`` on the recorded run, then ``compd replay`` of the
   model on a spindle-speed spectrum the plant was never run at (``compd sim
   --record … --program spectrum``, seed 7, as long as the plan).
"""

from __future__ import annotations

import asyncio
import contextlib
import csv
import io
import json
import signal
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from compd.cli import main as cli
from compd.offline.demo import start_daemon_at_rest
from drivers.sim.linuxcnc_machine import LinuxCncSimController
from drivers.sim.linuxcnc_spindle import LinuxCncSpindleMachine
from models import tomltext

ROOT = Path(__file__).resolve().parents[4]
SPEEDS = (3000, 6000, 9000)
#: the daemon's period, the model's (machine seconds; the example's model runs at 60 s)
PERIOD_S = 60.0
#: the plant's tick (machine seconds): a speed LinuxCNC sets is seen within one
PLANT_PERIOD_S = 10.0
TERMS = ("bearing", "motor", "column", "ambient")
#: LinuxCNC's interp_state when no program runs (linuxcnc.INTERP_IDLE)
INTERP_IDLE = 1


@dataclass(frozen=True)
class PlanRun:
    """One run's files and figures."""

    folder: Path
    hours: float
    time_scale: float
    #: real seconds LinuxCNC took over the program (its dwell: hours·3600/time_scale)
    program_real_s: float
    plant_ticks: int
    #: plant ticks that came late (each slows the plant's time against LinuxCNC's)
    plant_overruns: int
    #: the rows `compd run` recorded (its export as dicts of text)
    rows: list[dict[str, str]]

    @property
    def db(self) -> Path:
        return self.folder / "warmup.sqlite"

    def steps(self) -> list[tuple[int, float]]:
        """The record's spindle steps: (rpm, machine minutes held), in order."""
        out: list[tuple[int, float]] = []
        start = previous = None
        for row in self.rows:
            rpm, t_s = round(float(row["spindle_rpm"])), float(row["mono_s"])
            if rpm != previous:
                if previous is not None and start is not None:
                    out.append((previous, (t_s - start) / 60.0))
                start, previous = t_s, rpm
        if previous is not None and start is not None:
            out.append((previous, (float(self.rows[-1]["mono_s"]) - start) / 60.0))
        return out


def compd(argv: list[str]) -> dict[str, Any]:
    """`compd ARGV` in this process; its last JSON line (or {}); RuntimeError
    with its stderr when it fails."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli(argv)
    if code != 0:
        raise RuntimeError(f"compd {' '.join(argv)} exited {code}: {err.getvalue().strip()}")
    lines = out.getvalue().strip().splitlines()
    return json.loads(lines[-1]) if lines and lines[-1].startswith("{") else {}


def run_config(lcnc: LinuxCncSimController, folder: Path, recorder_toml: Path,
               time_scale: float) -> Path:
    """compd/examples/linuxcnc.toml at `time_scale`, the table and the growth
    (``dz_um``) as channels too, and the plan's [recorder]; its HAL names `lcnc`'s."""
    doc = tomllib.loads((ROOT / "compd" / "examples" / "linuxcnc.toml").read_text("utf-8"))
    doc["machine"].update(period_s=PERIOD_S, time_scale=time_scale)
    doc["controller"].update(timeout_s=0.4 * PERIOD_S / time_scale, connect_timeout_s=60.0)
    doc["channels"]["table"] = {**doc["channels"]["column"],
                                "address": {"pin": "table", "net": "compd-table"}}
    doc["channels"]["dz_um"] = {"address": {"pin": "dz-um", "net": "compd-growth_um"},
                                "unit": "um", "range": [-1000.0, 1000.0]}
    doc["state"]["dir"] = str(folder / "state")
    doc["recorder"] = tomllib.loads(recorder_toml.read_text("utf-8"))["recorder"]
    path = folder / "compd.toml"
    path.write_text(tomltext.dumps(lcnc.own_config(doc)), encoding="utf-8")
    return path


async def _run_program(lcnc: LinuxCncSimController, folder: Path, ngc: Path, config: Path,
                       time_scale: float, seed: int) -> tuple[float, int, int]:
    """LinuxCNC runs `ngc` while the plant follows its spindle and `compd run`
    records; (real seconds of the program, plant ticks, overruns). Raises
    `ForeignLinuxCnc` (the lock given back) where a LinuxCNC it did not start runs."""
    await lcnc.start()
    try:
        machine = LinuxCncSpindleMachine(lcnc, seed=seed, period_s=PLANT_PERIOD_S,
                                         speedup=time_scale)
        proc = await start_daemon_at_rest(machine, config, folder / "run.log",
                                          folder / "notify")
        try:
            machine.start()
            t0 = time.monotonic()
            await lcnc.control("run", str(ngc))
            while True:  # real time: LinuxCNC's dwell is the clock
                state = await lcnc.control("stat")
                if state["interp_state"] == INTERP_IDLE:
                    break
                await asyncio.sleep(0.2)
            program_s = time.monotonic() - t0
            # two daemon periods more: the last rest recorded to its end
            await asyncio.sleep(2 * PERIOD_S / time_scale)
            await machine.stop()
        finally:
            if proc.returncode is None:
                proc.send_signal(signal.SIGTERM)
            code = await proc.wait()
        if code != 0:
            raise RuntimeError(f"compd run exited {code}: see {folder / 'run.log'}")
        return program_s, machine.ticks, machine.overruns
    finally:
        await lcnc.stop()


def run_plan(folder: Path, *, hours: float = 2.0, time_scale: float = 120.0,
             seed: int = 3) -> PlanRun:
    """Plan, run in LinuxCNC and record (steps 1-3 of the module) in `folder`
    (LinuxCNC's task reads the program from it: made world-readable)."""
    folder.mkdir(parents=True, exist_ok=True)
    folder.chmod(0o755)
    ngc = folder / "warmup.ngc"
    compd(["plan", "--hours", f"{hours:g}", "--speeds", ",".join(map(str, SPEEDS)),
           "--dialect", "linuxcnc", "--time-scale", f"{time_scale:g}", "-o", str(ngc),
           "--force"])
    ngc.chmod(0o644)
    lcnc = LinuxCncSimController()
    config = run_config(lcnc, folder, folder / "warmup.recorder.toml", time_scale)
    program_s, ticks, overruns = asyncio.run(
        _run_program(lcnc, folder, ngc, config, time_scale, seed))
    exported = folder / "warmup.csv"
    compd(["export", str(folder / "warmup.sqlite"), "-o", str(exported), "--force"])
    with exported.open(encoding="utf-8", newline="") as f:
        rows = list(csv.DictReader(f))
    return PlanRun(folder, hours, time_scale, program_s, ticks, overruns, rows)


def fit_and_replay(run: PlanRun) -> tuple[dict[str, Any], dict[str, Any]]:
    """Step 4: `compd fit` on the record and `compd replay` of its model on an
    unseen spectrum; their JSON figures."""
    return fit_and_replay_record(run.db, run.folder / "model.toml", run.hours)


def fit_and_replay_record(record: Path, model: Path,
                          hours: float) -> tuple[dict[str, Any], dict[str, Any]]:
    """`compd fit` of `record` (a recorder database or a CSV) into `model`, and
    `compd replay` of it on a `hours` spectrum (seed 7) the plant never ran."""
    terms = [a for t in TERMS for a in ("--term", t)]
    fit = compd(["fit", str(record), "--column", "dz_um", *terms, "-o", str(model),
                 "--force", "--json"])
    spectrum = model.with_name("spectrum.csv")
    compd(["sim", "--record", str(spectrum), "--program", "spectrum", "--hours",
           f"{hours:g}", "--period-s", f"{PERIOD_S:g}", "--seed", "7", "--force"])
    replay = compd(["replay", str(model), str(spectrum), "--column", "dz_um", "--json"])
    return fit, replay
