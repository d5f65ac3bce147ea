"""LinuxCNC in the loop: a real, headless LinuxCNC (`drivers.sim.linuxcnc_machine`)
running a G-code program, the simulated plant feeding its temperature signals,
and the real daemon (in lockstep, `tests.harness`) compensating Z through
external offsets. Everything is checked on LinuxCNC's side: ``axis.z.eoffset``
and the HAL signals (read as ``halcmd getp`` does), ``linuxcnc.stat()``.

One LinuxCNC for the module (it takes seconds to start), held under the
machine's LinuxCNC lock (`drivers.sim.linuxcnc_host`: one LinuxCNC per machine,
whatever run, checkout or user wants one): a run that finds it held waits (its
module's setup, outside the tests' timeouts); skipped with the reason where
``linuxcnc-uspace`` is absent, and where a LinuxCNC this run did not start runs
(a shop's: never touched). Its signal and component names are the run's own
(`LinuxCncSimController.prefix`).

The figures (offset LinuxCNC applies against the offset compd wrote, the
largest step per period against the slew limit) are printed: ``-s`` shows them.
"""

from __future__ import annotations

import asyncio
import itertools
import json
import signal
import subprocess
import tomllib
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

import pytest
import pytest_asyncio

from compd.core.health import Cause
from compd.core.output import Status
from compd.offline.demo import start_daemon
from drivers.errors import BadAddress, ConnectionLost
from drivers.linuxcnc import LinuxCncDriver
from drivers.linuxcnc_options import LinuxCncPin
from drivers.sim.linuxcnc_machine import (
    PERMIT_DOUT,
    REZERO_DOUT,
    ForeignLinuxCnc,
    LinuxCncBusy,
    LinuxCncSimController,
    unavailable,
)
from drivers.sim.machine import SimMachine
from drivers.sim.programs import constant
from tests.configs import lockstep_config, write_doc
from tests.faults.invariants import watch
from tests.harness import Lockstep, until

WHY_NOT = unavailable()
pytestmark = [pytest.mark.skipif(WHY_NOT is not None, reason=str(WHY_NOT)),
              pytest.mark.asyncio(loop_scope="module"),
              # the test alone: the module's setup may wait for another run's LinuxCNC
              pytest.mark.timeout(600, func_only=True)]

ROOT = Path(__file__).resolve().parents[3]
PERIOD_S = 60.0
LIMIT_UM = 200.0
#: 0.6 µm a period: below the warming machine's fastest growth, so the slew limit binds
SLEW_UM_S = 0.01
STEP_UM = SLEW_UM_S * PERIOD_S
#: one count of axis.z.eoffset-counts (drivers.sim.linuxcnc_machine.COUNT_UM)
COUNT_UM = 0.1
SPEED_RPM = 9000.0
#: how close motion's external offset planner comes to the request before it stops
#: (its stopping criterion, TINY_DP: under a nanometre here)
SETTLED_UM = 1e-3
#: the machine's program: spindle on at the plant's speed, Z down, a long dwell
PROGRAM = f"""%
G21 G90 G17
M3 S{SPEED_RPM:g}
G1 Z-5 F600
G4 P3600
M5
M2
%
"""


@pytest_asyncio.fixture(scope="module", loop_scope="module")
async def lcnc(tmp_path_factory: pytest.TempPathFactory) -> AsyncIterator[LinuxCncSimController]:
    sim = LinuxCncSimController()
    try:
        await sim.start()
    except (ForeignLinuxCnc, LinuxCncBusy) as exc:
        pytest.skip(str(exc))
    try:
        ngc = tmp_path_factory.mktemp("ngc") / "warm.ngc"
        ngc.write_text(PROGRAM, encoding="ascii")
        ngc.parent.chmod(0o755)
        await sim.control("run", str(ngc))
        yield sim
    finally:
        await sim.stop()


def _config(sim: LinuxCncSimController, tmp_path: Path, **faults: Any) -> Path:
    doc = lockstep_config(sim, tmp_path, model="sim_machine", period_s=PERIOD_S,
                          limit_um=LIMIT_UM, slew_um_s=SLEW_UM_S)
    for state in ("machine_on", "estop", "homed"):
        doc["output"][state] = sim.states[state].model_dump()
    doc["faults"].update(faults)
    return write_doc(doc, tmp_path / "compd.toml")


def _rig(sim: LinuxCncSimController, tmp_path: Path, **faults: Any) -> Lockstep:
    machine = SimMachine(sim, program=constant(SPEED_RPM, heat_h=10.0, cool_h=1.0),
                         seed=3, period_s=PERIOD_S, repeat=False)
    return Lockstep(machine, _config(sim, tmp_path, **faults))


def _written(rig: Lockstep) -> float | None:
    """The offset the daemon's last cycle wrote (µm), None when it wrote none."""
    assert rig.daemon is not None and rig.daemon.loop.last_result is not None
    return rig.daemon.loop.last_result.writes.get("offset")


def _signal(name: str) -> float:
    """A HAL signal's value, as ``halcmd gets`` reads it."""
    out = subprocess.run(["halcmd", "-s", "gets", name], capture_output=True, text=True,
                         timeout=30, check=True)
    text = out.stdout.strip()
    return float({"TRUE": 1, "FALSE": 0}.get(text, text))


def _component_exists(name: str) -> bool:
    out = subprocess.run(["halcmd", "-s", "show", "comp", name], capture_output=True,
                         text=True, timeout=30, check=False)
    return any(line.split()[1:2] == [name] or name in line.split() for line in
               out.stdout.splitlines())


async def test_driver_joins_the_machines_signals(lcnc: LinuxCncSimController) -> None:
    state = await lcnc.control("stat")
    assert state["machine_on"] and all(state["homed"])
    driver = LinuxCncDriver(lcnc.endpoint, {**lcnc.channels, **lcnc.states}, lcnc.outputs_map,
                            timeout_s=10.0, connect_timeout_s=60.0,
                            component=lcnc.component)
    try:
        await driver.connect()
        await lcnc.publish({"bearing": 31.4, "ambient": 20.5})
        got = await driver.read(["bearing", "ambient", "spindle_rpm", "machine_on", "estop"])
        assert {n: s.value for n, s in got.items()} == pytest.approx(
            {"bearing": 31.4, "ambient": 20.5, "spindle_rpm": SPEED_RPM, "machine_on": 1.0,
             "estop": 0.0})
        before = (await driver.read(["offset"]))["offset"].value
        await driver.write({"offset": before + 3.7, "heartbeat": 7, "status": 1})
        hal = await lcnc.settled()
        assert hal["offset_um"] == pytest.approx(before + 3.7, abs=SETTLED_UM)
        assert (hal["heartbeat"], hal["status"]) == (7, 1)
        await driver.write({"offset": before})
        assert (await lcnc.settled())["offset_um"] == pytest.approx(before, abs=SETTLED_UM)
    finally:
        await driver.close()
    assert not _component_exists(lcnc.component)
    # a signal the HAL file does not make: refused at connect, naming it
    bad = LinuxCncDriver(lcnc.endpoint, {"bearing": LinuxCncPin(pin="b", net="no-such-net")},
                         {}, timeout_s=10.0, connect_timeout_s=60.0, component=lcnc.component)
    with pytest.raises(BadAddress, match="no-such-net"):
        await bad.connect()
    await bad.close()


async def test_z_offset_follows_the_model_under_the_slew_limit(
        lcnc: LinuxCncSimController, tmp_path: Path) -> None:
    rig = _rig(lcnc, tmp_path)
    seen: list[float] = []
    rows: list[tuple[float, float, float]] = []  # (written, LinuxCNC's, model)
    try:
        await rig.start()
        seen.append((await lcnc.settled())["offset_um"])
        for _ in range(150):
            await rig.step()
            hal = await lcnc.settled()
            written = _written(rig)
            assert written is not None and rig.daemon is not None
            result = rig.daemon.loop.last_result
            assert result is not None and result.model_um is not None
            rows.append((written, hal["offset_um"], result.model_um))
            seen.append(hal["offset_um"])
            assert hal["heartbeat"] == result.heartbeat and hal["status"] == result.status
        assert await rig.stop() == 0
    finally:
        await rig.close()
    diff = max(abs(w - s) for w, s, _ in rows)
    steps = [b - a for a, b in itertools.pairwise(seen)]
    # each period LinuxCNC's offset is within a count of the model, or moved toward
    # it by the whole slew step (the slew limit binds), never past it
    limited = 0
    for (_, s, m), step in zip(rows, steps, strict=True):
        if abs(s - m) > COUNT_UM + SETTLED_UM:
            assert abs(abs(step) - STEP_UM) <= SETTLED_UM and (m - s) * step > 0
            limited += 1
    print(json.dumps({"figure": "linuxcnc_offset_vs_written", "periods": len(rows),
                      "max_diff_um": diff, "max_step_um": max(map(abs, steps)),
                      "slew_step_um": STEP_UM,
                      "max_step_over_slew": max(map(abs, steps)) / STEP_UM,
                      "slew_limited_periods": limited, "final_offset_um": seen[-1],
                      "final_model_um": rows[-1][2]}))
    assert diff <= SETTLED_UM  # what LinuxCNC applies is what compd wrote
    assert max(map(abs, steps)) <= STEP_UM + SETTLED_UM
    assert limited >= 10 and seen[-1] > 10.0  # the slew limit bound; the offset followed
    assert abs(seen[-1] - rows[-1][2]) <= COUNT_UM + SETTLED_UM  # caught up by the end


async def test_machine_off_and_estop_are_held_without_a_write_fight(
        lcnc: LinuxCncSimController, tmp_path: Path) -> None:
    rig = _rig(lcnc, tmp_path)
    try:
        await rig.start()
        await rig.step(40)
        warm = (await lcnc.settled())["offset_um"]
        assert warm > 5.0
        for off, word in (("off", "machine_off"), ("estop", "estop")):
            counts = _signal(f"{lcnc.prefix}-eoffset-counts")
            await lcnc.control(off)
            for _ in range(5):
                await rig.step()
                assert _written(rig) is None  # no offset written while LinuxCNC is off
                status = int((await lcnc.settled())["status"])
                assert status & Status.CONTROLLER_OFF and not status & Status.ALARM
            assert _signal(f"{lcnc.prefix}-eoffset-counts") == counts  # counts left alone
            assert rig.logs[-1].names().count("controller_off") == (1 if off == "off" else 2)
            fields = [f for _, e, f in rig.logs[-1].events if e == "controller_off"][-1]
            assert fields["reason"] == word
            await lcnc.control("on")  # LinuxCNC zeroes the external offset at machine on
            assert (await lcnc.settled())["offset_um"] == pytest.approx(0.0, abs=SETTLED_UM)
            previous = 0.0
            for _ in range(3):  # ramps back from 0 at the slew limit, no alarm
                await rig.step()
                hal = await lcnc.settled()
                assert 0.0 < hal["offset_um"] - previous <= STEP_UM + SETTLED_UM
                assert not int(hal["status"]) & (Status.ALARM | Status.READBACK_MISMATCH)
                previous = hal["offset_um"]
        names = rig.logs[-1].names()
        assert "write_failed" not in names and "readback_mismatch" not in names
        assert names.count("controller_on") == 2
        assert await rig.stop() == 0
    finally:
        await rig.close()


async def test_death_holds_the_offset_and_a_restart_resumes_without_a_jump(
        lcnc: LinuxCncSimController, tmp_path: Path) -> None:
    rig = _rig(lcnc, tmp_path)
    try:
        await rig.start()
        await rig.step(40)
        held = (await lcnc.settled())["offset_um"]
        assert held > 5.0
        daemon = rig.daemon
        assert daemon is not None and daemon.running.driver is not None
        await rig.kill9()
        # the kernel closes a killed process' pipes: its HAL side reads end-of-file
        await daemon.running.driver.close()
        assert not _component_exists(lcnc.component)
        await rig.idle(5)  # no daemon: the signal keeps the last counts, the offset holds
        assert (await lcnc.settled())["offset_um"] == pytest.approx(held, abs=SETTLED_UM)
        await rig.start()
        # the restart's first cycle: the checkpoint (every 30 cycles) is older than
        # the offset held, so the read-back is foreign (READBACK_MISMATCH while the
        # output ramps back, as for every protocol) and the output ramps from it
        previous = (await lcnc.settled())["offset_um"]
        assert abs(previous - held) <= STEP_UM + SETTLED_UM
        for _ in range(5):
            await rig.step()
            hal = await lcnc.settled()
            assert abs(hal["offset_um"] - previous) <= STEP_UM + SETTLED_UM
            previous = hal["offset_um"]
        # SIGTERM with shutdown = "hold": the offset stays where it is
        assert await rig.stop() == 0
        assert (await lcnc.settled())["offset_um"] == pytest.approx(previous, abs=SETTLED_UM)
        assert not _component_exists(lcnc.component)
    finally:
        await rig.close()


async def test_the_shipped_example_runs_against_the_machines_hal_file(
        lcnc: LinuxCncSimController, tmp_path: Path) -> None:
    """`compd/examples/linuxcnc.toml` joins the signals the HAL file of
    `docs/protocols.md` makes (the test machine's, under the run's own names), as it
    is but its state dir."""
    doc = lcnc.own_config(tomllib.loads(
        (ROOT / "compd" / "examples" / "linuxcnc.toml").read_text("utf-8")))
    doc["state"]["dir"] = str(tmp_path / "state")
    machine = SimMachine(lcnc, program=constant(SPEED_RPM, heat_h=10.0, cool_h=1.0),
                         seed=5, period_s=float(doc["machine"]["period_s"]), repeat=False)
    rig = Lockstep(machine, write_doc(doc, tmp_path / "compd.toml"))
    try:
        await rig.start()
        await rig.step(10)
        written = _written(rig)
        assert written is not None
        assert (await lcnc.settled())["offset_um"] == pytest.approx(written, abs=SETTLED_UM)
        assert await rig.stop() == 0
    finally:
        await rig.close()


async def test_compd_run_process_killed_leaves_the_offset_held(
        lcnc: LinuxCncSimController, tmp_path: Path) -> None:
    """`compd run` as a process, in real time: kill -9 closes its pipe, its HAL side
    ends, HAL removes the component and LinuxCNC keeps the last counts; a restarted
    `compd run` compensates again and ends on SIGTERM with status 0, offset held."""
    doc = tomllib.loads(_config(lcnc, tmp_path).read_text("utf-8"))
    doc["machine"]["time_scale"] = PERIOD_S / 0.5  # a cycle every half second
    doc["controller"]["timeout_s"] = 0.25
    doc["controller"]["connect_timeout_s"] = 60.0
    config = write_doc(doc, tmp_path / "compd.toml")
    await lcnc.publish({"bearing": 35.0, "motor": 40.0, "column": 22.0, "ambient": 20.0})

    async def offset_in_counts() -> float:
        return _signal(f"{lcnc.prefix}-eoffset-counts")

    start = (await lcnc.settled())["offset_um"]
    proc = await start_daemon(config, tmp_path / "run1.log", tmp_path / "notify1")
    # the model starts at rest on today's temperatures: the machine warms after
    await lcnc.publish({"bearing": 40.0, "motor": 48.0})
    try:
        async def moved() -> bool:
            return abs((await lcnc.settled())["offset_um"] - start) > 1.0
        await until(moved, what="compd run moved LinuxCNC's offset", every_s=0.05)
        proc.kill()
        await proc.wait()

        async def gone() -> bool:
            return not _component_exists(lcnc.component)
        await until(gone, what="the HAL side of a killed compd ended", every_s=0.05)
        counts = await offset_in_counts()
        held = (await lcnc.settled())["offset_um"]
        await lcnc.control("stat")  # LinuxCNC runs on meanwhile; nobody drives the counts
        # the signal keeps the counts compd wrote last, and LinuxCNC the offset
        assert await offset_in_counts() == counts
        assert (await lcnc.settled())["offset_um"] == pytest.approx(held, abs=SETTLED_UM)
        assert abs(held - start) > 1.0
        beats = _signal(f"{lcnc.prefix}-heartbeat")
        proc = await start_daemon(config, tmp_path / "run2.log", tmp_path / "notify2")

        async def beating() -> bool:
            return _signal(f"{lcnc.prefix}-heartbeat") != beats
        await until(beating, what="a restarted compd run's heartbeat reached HAL", every_s=0.05)
        proc.send_signal(signal.SIGTERM)
        assert await proc.wait() == 0
        await until(gone, what="the HAL side of a stopped compd ended", every_s=0.05)
        last = (await lcnc.settled())["offset_um"]
        assert abs(last - held) <= 2 * STEP_UM  # ramped, never jumped; then held
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()


async def test_a_hal_side_killed_9_is_stepped_around(lcnc: LinuxCncSimController) -> None:
    """SIGKILL of the HAL side (systemd's last resort on the whole unit) leaves its
    component in HAL for good, still driving the signals: the next HAL side takes
    another name, unlinks the dead one's pins (the signals keep their values: the
    offset holds) and drives them itself."""
    # its own name: what it leaves behind stays in this LinuxCNC for the other tests
    driver = LinuxCncDriver(lcnc.endpoint, {**lcnc.channels}, lcnc.outputs_map,
                            timeout_s=10.0, connect_timeout_s=60.0,
                            component=f"{lcnc.prefix}-k9")
    try:
        await driver.connect()
        before = (await lcnc.settled())["offset_um"]
        await driver.write({"offset": before + 1.0, "heartbeat": 11})
        session = driver._link.session
        assert session is not None
        session.proc.kill()
        await session.proc.wait()
        assert _component_exists(f"{lcnc.prefix}-k9")  # left behind, HAL cannot remove it
        held = (await lcnc.settled())["offset_um"]
        assert held == pytest.approx(before + 1.0, abs=SETTLED_UM)
        with pytest.raises(ConnectionLost):  # the link sees its session gone
            await driver.read(["offset"])
        await driver.connect()  # a new HAL side (the backoff's attempt, made now)
        assert _component_exists(f"{lcnc.prefix}-k9-2")
        assert (await driver.read(["offset"]))["offset"].value == pytest.approx(
            held, abs=SETTLED_UM)
        await driver.write({"offset": before, "heartbeat": 12})
        hal = await lcnc.settled()
        assert hal["offset_um"] == pytest.approx(before, abs=SETTLED_UM)
        assert hal["heartbeat"] == 12
    finally:
        await driver.close()


async def test_a_hal_side_start_outlives_a_read_that_gave_up(
        lcnc: LinuxCncSimController) -> None:
    """Starting the HAL side (a Python, HAL, the joins) takes longer than a fast
    cycle's read may wait: a read that gives up leaves the start going on, and the
    next attempt takes that HAL side instead of killing it and starting again."""
    driver = LinuxCncDriver(lcnc.endpoint, {"bearing": lcnc.channels["bearing"]}, {},
                            timeout_s=10.0, connect_timeout_s=60.0,
                            component=f"{lcnc.prefix}-slow")
    try:
        with pytest.raises(TimeoutError):
            await asyncio.wait_for(driver.read(["bearing"]), 0.001)
        starting = driver._link._connecting  # the link's own task (`drivers.link`)
        assert starting is not None and not starting.done()
        await driver.connect()
        assert driver._link.session is starting.result()
        await lcnc.publish({"bearing": 33.3})
        assert (await driver.read(["bearing"]))["bearing"].value == pytest.approx(33.3)
    finally:
        await driver.close()
    assert not _component_exists(f"{lcnc.prefix}-slow")


def _pin(name: str) -> float:
    """A HAL pin's value, as ``halcmd getp`` reads it."""
    out = subprocess.run(["halcmd", "-s", "getp", name], capture_output=True, text=True,
                         timeout=30, check=True)
    text = out.stdout.strip()
    return float({"TRUE": 1, "FALSE": 0}.get(text, text))


def _writer(signal_name: str) -> str | None:
    """The pin driving a HAL signal (``halcmd show sig``), None when none does."""
    out = subprocess.run(["halcmd", "show", "sig", signal_name], capture_output=True,
                         text=True, timeout=30, check=True).stdout
    return next((line.split()[1] for line in out.splitlines()
                 if line.split()[:1] == ["<=="]), None)


def _program_in(folder: Path) -> Path:
    """The module's program, written in `folder` (LinuxCNC's task reads it)."""
    ngc = folder / "warm.ngc"
    ngc.write_text(PROGRAM, encoding="ascii")
    folder.chmod(0o755)
    return ngc


async def _run_program_again(lcnc: LinuxCncSimController, folder: Path) -> None:
    """The module's program, for the tests after one that stopped it."""
    await lcnc.control("run", str(_program_in(folder)))


async def test_a_component_named_like_linuxcncs_pins_never_unlinks_them(
        lcnc: LinuxCncSimController) -> None:
    """A component named like LinuxCNC's own pins (``spindle``: motion's
    ``spindle.0.speed-out`` drives ``spindle-speed-cmd``; ``J0_pid``: basic_sim's
    PID loop) is refused by the driver, and a HAL side given one all the same
    refuses to start: no component of that name exists, so no kill and restart can
    ever take LinuxCNC's pins for its own and unlink them. The spindle command keeps
    its writer (benchmarks/bench_hal_kills_linuxcnc.py: the whole signal table
    through 20 kills)."""
    speed = {"spindle_rpm": lcnc.channels["spindle_rpm"]}
    with pytest.raises(ValueError, match="LinuxCNC uses"):
        LinuxCncDriver(lcnc.endpoint, speed, {}, component="spindle")
    for name in ("spindle", "J0_pid"):
        driver = LinuxCncDriver(lcnc.endpoint, speed, {}, timeout_s=10.0,
                                connect_timeout_s=60.0, component=lcnc.component)
        driver.component = name  # past the driver's own check: the HAL side's
        try:
            with pytest.raises(BadAddress, match=rf"pin {name}\."):
                await driver.connect()
        finally:
            await driver.close()
        assert not _component_exists(name)
    assert _writer("spindle-speed-cmd") == "spindle.0.speed-out"
    assert _signal("spindle-speed-cmd") == _pin("spindle.0.speed-out")


async def test_dead_components_are_bounded(lcnc: LinuxCncSimController,
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    """Each HAL side killed with SIGKILL leaves its component in HAL (only a
    LinuxCNC restart frees it): the next start steps around at most the bound, then
    refuses, naming them, instead of piling up components."""
    import drivers.linuxcnc

    monkeypatch.setattr(drivers.linuxcnc, "MAX_LEFT_BEHIND", 2, raising=False)
    name = f"{lcnc.prefix}-b"
    driver = LinuxCncDriver(lcnc.endpoint, {"bearing": lcnc.channels["bearing"]},
                            {"heartbeat": lcnc.outputs_map["heartbeat"]}, timeout_s=10.0,
                            connect_timeout_s=60.0, component=name)
    try:
        for kill in range(3):
            await driver.connect()
            session = driver._link.session
            assert session is not None
            session.proc.kill()
            await session.proc.wait()
            with pytest.raises(ConnectionLost):
                await driver.read(["bearing"])
            assert _component_exists(name if kill == 0 else f"{name}-{kill + 1}")
        with pytest.raises(ConnectionLost, match="3 components of killed compd HAL sides"):
            await driver.connect()
        assert not _component_exists(f"{name}-4")
        # the last one killed still holds the heartbeat signal at its last value (a
        # stopped heartbeat, which the PLC sees), until a start is allowed again
        assert _writer(f"{lcnc.prefix}-heartbeat") == f"{name}-3.heartbeat"
    finally:
        await driver.close()


async def test_an_unhomed_machine_is_controller_off_not_a_write_fault(
        lcnc: LinuxCncSimController, tmp_path: Path) -> None:
    """LinuxCNC takes no external offset before it is homed: with [output] homed
    compd holds (CONTROLLER_OFF, reason not_homed) instead of having its writes
    refused into a WRITE_FAULT alarm, and ramps from what LinuxCNC holds once homed."""
    from compd.core.health import WRITE_FAULT_AFTER

    rig = _rig(lcnc, tmp_path)
    try:
        await rig.start()
        await rig.step(3)
        await lcnc.control("unhome")
        assert _pin("motion.is-all-homed") == 0.0
        for _ in range(WRITE_FAULT_AFTER + 2):
            await rig.step()
            assert _written(rig) is None
            status = int((await lcnc.settled())["status"])
            assert status & Status.CONTROLLER_OFF
            assert not status & (Status.ALARM | Status.WRITE_FAULT)
        fields = [f for _, e, f in rig.logs[-1].events if e == "controller_off"][-1]
        assert fields["reason"] == "not_homed"
        await lcnc.control("on")  # homes again
        await rig.step(2)
        assert _written(rig) is not None
        names = rig.logs[-1].names()
        assert "write_failed" not in names and "readback_mismatch" not in names
        assert await rig.stop() == 0
    finally:
        await rig.close()
        await _run_program_again(lcnc, tmp_path)


async def test_an_offset_clipped_at_a_soft_limit_reads_back_as_held(
        lcnc: LinuxCncSimController, tmp_path: Path) -> None:
    """Z a micrometre under its soft limit: LinuxCNC clips the external offset
    (``motion.eoffset-limited``) and applies less than compd asked. That is
    LinuxCNC's limit, not a second writer: the offset read back is the one LinuxCNC
    holds from compd, so the daemon does not see a foreign offset every cycle."""
    driver = LinuxCncDriver(lcnc.endpoint, {}, {"offset": lcnc.outputs_map["offset"]},
                            timeout_s=10.0, connect_timeout_s=60.0,
                            component=f"{lcnc.prefix}-clip")
    try:
        await driver.connect()
        held = (await driver.read(["offset"]))["offset"].value
        top = 100.0 - 0.001 - held / 1000.0  # MAX_LIMIT 100 mm, 1 µm of room
        await lcnc.control("mdi", f"G53 G0 Z{top:.6f}")
        await driver.write({"offset": held + 5.0})
        await lcnc.settled(deadline_s=1.0)  # motion stops at the limit: never settles
        assert _pin("motion.eoffset-limited") == 1.0
        applied = (await lcnc.hal())["offset_um"]
        assert applied < held + 2.0  # clipped
        assert (await driver.read(["offset"]))["offset"].value == pytest.approx(
            held + 5.0, abs=COUNT_UM)
        await driver.write({"offset": held})
        assert (await lcnc.settled())["offset_um"] == pytest.approx(held, abs=SETTLED_UM)
        assert _pin("motion.eoffset-limited") == 0.0
    finally:
        await driver.close()
        await lcnc.control("mdi", "G53 G0 Z0")
        await _run_program_again(lcnc, tmp_path)


async def _settled_steps(rig: Lockstep, lcnc: LinuxCncSimController, start_um: float,
                         until: Callable[[float, float], bool], limit: int = 60) -> list[float]:
    """Step until `until(LinuxCNC's offset, the model)` holds; LinuxCNC's offset after
    each period, from `start_um`."""
    seen = [start_um]
    for _ in range(limit):
        await rig.step()
        assert rig.daemon is not None and rig.daemon.loop.last_result is not None
        model = rig.daemon.loop.last_result.model_um
        assert model is not None
        seen.append((await lcnc.settled())["offset_um"])
        if until(seen[-1], model):
            return seen
    pytest.fail(f"not within {limit} periods: {seen[-5:]}")


async def test_g_code_permits_offset_changes_and_re_zeroes_by_m_code(
        lcnc: LinuxCncSimController, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``[output] update_permitted`` and ``rezero`` as HAL pins (``type = "bit"``) the
    machine's HAL joins to motion's digital outputs, set by G-code in MDI (``M64``/
    ``M65 P<n>``; docs/protocols.md §10). While the permit is low, what LinuxCNC applies
    (``axis.z.eoffset``) and compd's counts stand still, the model steps on and the
    status word says HOLDING; raised, the change ramps in at the slew limit; an
    ``M64``/``M65`` pulse re-zeroes, the offset ramping to the new zero, never stepped.
    The output invariants are checked on every cycle (`tests.faults.invariants`)."""
    inv = watch(monkeypatch)
    doc = tomllib.loads(_config(lcnc, tmp_path).read_text("utf-8"))
    for name, address in lcnc.mcode_inputs.items():
        doc["output"][name] = address.model_dump()
    machine = SimMachine(lcnc, program=constant(SPEED_RPM, heat_h=10.0, cool_h=1.0),
                         seed=7, period_s=PERIOD_S, repeat=False)
    rig = Lockstep(machine, write_doc(doc, tmp_path / "compd.toml"))

    async def mcode(on: bool, dout: int) -> None:
        await lcnc.control("mdi", f"M{64 if on else 65} P{dout}")

    def last() -> Any:
        assert rig.daemon is not None and rig.daemon.loop.last_result is not None
        return rig.daemon.loop.last_result

    try:
        await mcode(True, PERMIT_DOUT)  # between cuts: changes permitted
        await mcode(False, REZERO_DOUT)
        await rig.start()
        await rig.step(30)
        assert _pin(f"{lcnc.component}.update-permitted") == 1.0
        assert last().cause is Cause.IN_FORCE and last().stage_um > 3.0

        await mcode(False, PERMIT_DOUT)  # a cut starts: no change until it ends
        await rig.step()
        held = (await lcnc.settled())["offset_um"]
        counts = _signal(f"{lcnc.prefix}-eoffset-counts")
        model_from = last().model_um
        for _ in range(8):
            await rig.step()
            assert last().cause is Cause.WAITING_FOR_PERMISSION
            hal = await lcnc.settled()
            assert hal["offset_um"] == pytest.approx(held, abs=SETTLED_UM)
            assert int(hal["status"]) & Status.HOLDING and not int(hal["status"]) & Status.ALARM
        assert _signal(f"{lcnc.prefix}-eoffset-counts") == counts
        assert last().model_um > model_from + STEP_UM  # the model stepped on meanwhile
        pending = last().snapshot.pending_um
        assert pending is not None and pending > 2 * STEP_UM

        await mcode(True, PERMIT_DOUT)  # the cut ended: the change ramps in
        seen = await _settled_steps(rig, lcnc, held,
                                    lambda off, model: abs(off - model) <= COUNT_UM)
        steps = [abs(b - a) for a, b in itertools.pairwise(seen)]
        assert max(steps) <= STEP_UM + SETTLED_UM
        assert max(steps) >= STEP_UM - SETTLED_UM  # the slew limit bound: no jump
        names = rig.logs[-1].names()
        assert "permission_waiting" in names and "permission_granted" in names

        before = seen[-1]
        await mcode(True, REZERO_DOUT)  # the touch-off's pulse
        await rig.step()
        assert rig.daemon is not None and rig.daemon.running.cycle is not None
        assert rig.daemon.running.cycle.models.zero_by == "controller input [output] rezero"
        await mcode(False, REZERO_DOUT)
        after = (await lcnc.settled())["offset_um"]
        seen = await _settled_steps(rig, lcnc, after,
                                    lambda off, model: abs(off - model) <= COUNT_UM)
        steps = [abs(b - a) for a, b in itertools.pairwise([before, *seen])]
        assert max(steps) <= STEP_UM + SETTLED_UM  # no step at the tool
        assert abs(seen[-1]) < before - 3.0  # the growth since the touch-off only
        assert rig.logs[-1].names().count("rezero") == 1  # one pulse, one re-zero
        assert await rig.stop() == 0
    finally:
        await rig.close()
        await _run_program_again(lcnc, tmp_path)
    print(json.dumps({"figure": "linuxcnc_mcode_permit_rezero", "held_um": held,
                      "pending_um": pending, "rezero_from_um": before,
                      "max_step_um": max(steps), "slew_step_um": STEP_UM}))
    assert inv.total_cycles > 40 and not inv.violations


async def test_linuxcncs_own_error_reaches_the_tests_stat(
        lcnc: LinuxCncSimController) -> None:
    """A move LinuxCNC refuses (past X's soft limit) is told on its error channel, and
    the test machine's ``stat`` carries that message, so a test that waits on motion can
    say why the machine stopped instead of only that it did."""
    stat = await lcnc.control("mdi", "G53 G0 X500")
    assert any("limit" in e.lower() for e in stat["errors"]), stat
    assert (await lcnc.control("stat"))["errors"] == []  # read once, then gone
