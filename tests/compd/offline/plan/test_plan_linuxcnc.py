"""A `compd plan` program of 2 h run end to end in a real, headless LinuxCNC
(`tests.compd.offline.plan.plan_linuxcnc_run`): the program's spindle steps reach the
record `compd run` writes, in the plan's order and for the plan's minutes,
the plant's growth follows them (it turns at LinuxCNC's speed), and `compd
fit` fits the database into a model that also holds on a spectrum it never
saw. At time scale 240 (30 s of dwell); slow (a minute of real time, and
LinuxCNC's one-per-machine lock): ``pytest -m slow``. The figures at 120:
benchmarks/bench_plan_linuxcnc.py."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest

from drivers.sim import linuxcnc_host
from drivers.sim.linuxcnc_machine import ForeignLinuxCnc, LinuxCncBusy, unavailable
from tests.compd.offline.plan.plan_linuxcnc_run import SPEEDS, fit_and_replay, run_plan

WHY_NOT = unavailable()
pytestmark = [pytest.mark.skipif(WHY_NOT is not None, reason=str(WHY_NOT)),
              pytest.mark.slow,
              # the test alone: `machine` may wait for another run's LinuxCNC first
              pytest.mark.timeout(900, func_only=True)]

HOURS = 2.0
TIME_SCALE = 240.0
#: the plan's step: 2 h over 3 speeds twice and 2 rests, 15 min each
STEP_MIN = 15.0
#: a step's edges as the record sees them: one daemon period each (1 min), and a
#: plant tick (10 s) late at most
EDGE_MIN = 1.0 + 10.0 / 60.0


def _runs(rows: list[dict[str, str]]) -> list[tuple[int, list[float]]]:
    """The record's growth (dz_um) in runs of one spindle speed, in order."""
    out: list[tuple[int, list[float]]] = []
    for row in rows:
        rpm = round(float(row["spindle_rpm"]))
        if not out or out[-1][0] != rpm:
            out.append((rpm, []))
        out[-1][1].append(float(row["dz_um"]))
    return out


@pytest.fixture
def machine() -> Iterator[None]:
    """The machine's LinuxCNC lock, waited for outside the test's timeout (another
    run may hold it for minutes); a skip where a LinuxCNC this run did not start runs."""
    try:
        linuxcnc_host.acquire()
    except (ForeignLinuxCnc, LinuxCncBusy) as exc:
        pytest.skip(str(exc))
    try:
        yield
    finally:
        linuxcnc_host.release()


@pytest.mark.usefixtures("machine")
def test_a_plan_run_in_linuxcnc_is_recorded_and_fitted(tmp_path: Path) -> None:
    run = run_plan(tmp_path, hours=HOURS, time_scale=TIME_SCALE)
    # LinuxCNC dwelled the program's 30 s (its task polls every 10 ms; the start waits)
    assert HOURS * 3600.0 / TIME_SCALE <= run.program_real_s <= 2 * HOURS * 3600 / TIME_SCALE
    steps = run.steps()
    assert steps[0][0] == 0  # the daemon's first cycle: the machine at rest
    up = sorted(SPEEDS)
    assert [rpm for rpm, _ in steps[1:]] == [*up, 0, *reversed(up), 0]
    for _, minutes in steps[1:-1]:  # each held for the plan's minutes
        assert abs(minutes - STEP_MIN) <= EDGE_MIN, steps
    # the plant turned at LinuxCNC's speed: its growth (lagging the heat, as a
    # machine's does) rises the faster the higher the step, and falls at the end
    runs = _runs(run.rows)
    assert [rpm for rpm, _ in runs] == [rpm for rpm, _ in steps]
    rise = [dz[-1] - dz[0] for _, dz in runs[1:4]]
    assert 0.0 < rise[0] < rise[1] < rise[2], rise
    rest = runs[4][1]
    assert rest[-1] < max(rest) and runs[-1][1][-1] < runs[-1][1][0] - 3.0
    assert max(max(dz) for _, dz in runs) > 10.0
    fit, replay = fit_and_replay(run)
    print(json.dumps({"figure": "plan_linuxcnc", "time_scale": TIME_SCALE,
                      "program_real_s": run.program_real_s, "rows": len(run.rows),
                      "overruns": run.plant_overruns, "steps": steps,
                      "fit_percent": fit["fit_percent"],
                      "replay_fit_percent": replay["fit_percent"],
                      "replay_rms_um": replay["rms_um"]}))
    assert (tmp_path / "model.toml").is_file()
    assert fit["fit_percent"] > 90.0
    assert replay["fit_percent"] > 75.0 and replay["range_reduction"] > 3.0
