"""Through the wire: a model worse than none is caught by the probes.

The simulated Modbus controller, the in-process daemon on the fake clock (one
machine second a cycle, exactly), a bearing that warms the machine, and a model
DELIBERATELY miscalibrated: sp2 with every term's sign flipped, so the
compensation doubles the error the wrong way. A measuring cycle every PROBE_EVERY
cycles leaves what a touch probe on a compensating machine sees (the true growth,
sp2's own, minus the offset in force, plus noise) and advances its counter.

The guard "no model worse than none" ([adaptation] guard_window = 3) judges only
probes the estimator accepted (shadow mode: the plain model stays in force, so the
probes keep measuring it); it must trip within three accepted probes once the
compensation is worse than none, raise MODEL_WORSE and ALARM, hold the offset for
hold_s, then ramp it to zero with no step beyond the slew limit. Meanwhile every
face says so: `compd health --url` and `--state-dir` exit 1 naming
model_worse_than_none, `compd status` names the guard (never "inputs invalid"),
and the log's hold and ramp carry ``reason=model_worse_than_none``.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import io
import random
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

from compd.commands import health as health_cmd
from compd.commands import status as status_cmd
from compd.core.adaptation import DISAGREE_AFTER, AdaptationSettings, ProbeReading, ProbeStage
from compd.core.faults import Event, FaultState
from compd.core.health import Cause
from compd.core.output import Status
from compd.core.plan import AdaptationView
from compd.faces.status import operator_state
from compd.infiles import load_model
from compd.runtime.daemon import Daemon
from compd.runtime.driver_setup import build_driver
from compd.runtime.sdnotify import Notifier
from compd.testing import FakeClock
from drivers.base import Driver
from drivers.sim.modbus_server import ModbusSimController
from drivers.sim.ports import free_tcp_port
from models.adaptation import AdaptationParams
from tests.configs import make_config
from tests.faults.clocked_driver import ClockedDriver
from tests.harness import EventLog
from tests.shipped import LIBRARY

SLEW_UM_S = 1.0
HOLD_S = 10.0
PROBE_EVERY = 10
CYCLES = 400
SP2 = LIBRARY / "sp2.toml"


def _miscalibrated(tmp_path: Path) -> Path:
    """sp2 with every term's sign flipped (gain = -1)."""
    text = SP2.read_text(encoding="utf-8").replace("[[terms]]\n", "[[terms]]\ngain = -1.0\n")
    p = tmp_path / "wrong.toml"
    p.write_text(text, encoding="utf-8")
    assert [t.gain for t in load_model(p).terms] == [-1.0, -1.0]
    return p


class Watch(ClockedDriver):
    """The real Modbus driver; before each read the fake clock moves one period and
    the plant publishes the next temperatures (and, every PROBE_EVERY reads, a probe);
    after each cycle the offset in force, the status word and the cause are noted."""

    def __init__(self, inner: Driver, clock: FakeClock,
                 plant: Callable[[int], Awaitable[None]]) -> None:
        super().__init__(inner, clock, plant)
        self.offsets: list[float] = []
        self.statuses: list[int] = []
        self.causes: list[Cause] = []
        #: (cycle index, accepted by the estimator, error with, error without) per probe
        self.probes: list[tuple[int, bool, float, float]] = []

    def note(self, result: Any) -> None:
        probe = result.probe
        if probe is not None and probe["measured_um"] is not None:
            with_um = probe["value_um"]  # the residual: the error at the tool with it
            self.probes.append((len(self.offsets), probe["accepted"], with_um,
                                probe["measured_um"]))
        self.offsets.append(result.stage_um)
        self.statuses.append(result.status)
        self.causes.append(result.cause)


def _health(*argv: str) -> tuple[int, str]:
    """`compd health ARGV` in this process: its exit status and its line."""
    parser = argparse.ArgumentParser()
    health_cmd.add_arguments(parser)
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = health_cmd.run(parser.parse_args([*argv, "--max-age-s", "600"]))
    return code, out.getvalue().strip()


async def test_a_model_worse_than_none_is_caught_within_three_probes_and_ramped_to_zero(
        tmp_path: Path) -> None:
    sim = ModbusSimController()
    await sim.start()
    truth = load_model("sp2")
    rng = random.Random(20)
    probes: list[tuple[int, float, float]] = []  # (read index, the probe's value, offset)
    seen: dict[str, Any] = {}
    port = free_tcp_port("127.0.0.1")
    try:
        await sim.publish({"bearing": 20.0, "ambient": 20.0, "probe_value": 0.0,
                           "probe_counter": 1.0})
        cfg = make_config(sim, tmp_path, time_scale=1.0, slew_um_s=SLEW_UM_S,
                          model=str(_miscalibrated(tmp_path)), overrides={
                              "faults": {"hold_s": HOLD_S},
                              "state": {"checkpoint_every": 10},
                              "telemetry": {"metrics_port": port},
                              "faces": {"http": {"enabled": True}},
                              "adaptation": {
                                  "enabled": True, "mode": "shadow", "measures": "residual",
                                  "guard_window": 3,
                                  "probe_value": sim.probes["probe_value"].model_dump(),
                                  "probe_counter": sim.probes["probe_counter"].model_dump()}})
        clock = FakeClock(period_s=cfg.real_period_s)
        truth.set_references({"bearing": 20.0, "ambient": 20.0})
        daemon: Daemon | None = None
        url = f"http://127.0.0.1:{port}/"

        async def ask(when: str) -> None:
            """Every face, as a user asks it, at this cycle."""
            seen[when] = (
                await asyncio.to_thread(_health, "--url", url),
                await asyncio.to_thread(_health, "--state-dir", str(tmp_path / "state")),
                status_cmd.describe(await asyncio.to_thread(
                    status_cmd.fetch, status_cmd.status_url(url), 5.0)))

        async def plant(index: int) -> None:
            assert daemon is not None
            if index >= CYCLES:
                daemon.request_stop()
            last = daemon.loop.last_result
            if last is not None and "before" not in seen and last.cause is Cause.IN_FORCE \
                    and index > 25:
                await ask("before")
            if last is not None and last.cause is Cause.MODEL_WORSE_THAN_NONE:
                if last.state is FaultState.HOLD and "hold" not in seen:
                    await ask("hold")
                if last.state is FaultState.RAMP and "ramp" not in seen:
                    await ask("ramp")
            bearing = 20.0 + min(index, 300) / 300 * 2.0 + rng.gauss(0.0, 0.01)
            sample = {"bearing": bearing, "ambient": 20.0}
            growth = truth.step(sample)
            values: dict[str, float] = dict(sample)
            if index and index % PROBE_EVERY == 0:
                in_force = (await sim.outputs())["offset"]
                value = growth - in_force + rng.gauss(0.0, 0.2)
                values.update(probe_value=value, probe_counter=1.0 + len(probes) + 1)
                probes.append((index, value, in_force))
            await sim.publish(values)

        watch = Watch(build_driver(cfg), clock, plant)
        daemon = Daemon(cfg, driver=watch, notifier=Notifier(None), clock=clock)
        watch.daemon = daemon
        daemon.journal.log = EventLog()
        assert await asyncio.wait_for(daemon.run(), 300.0) == 0
    finally:
        await sim.stop()
    log = daemon.journal.log
    assert isinstance(log, EventLog)
    tripped = [(lvl, f) for lvl, e, f in log.events if e == "model_worse_than_none"]
    assert len(tripped) == 1, log.names()
    level, fields = tripped[0]
    assert level == "error" and fields["accepted_probes"] == 3
    assert abs(fields["error_with_um"]) > abs(fields["error_without_um"])
    # caught at the third accepted probe in a row that showed the compensation worse
    # than none (the error at the tool with it beyond the error without it); the
    # probes the estimator refused in between are no evidence either way
    accepted = [(k, abs(w) > abs(wo) + 1.0) for k, ok, w, wo in watch.probes if ok]
    third = next(accepted[j + 2][0] for j in range(len(accepted) - 2)
                 if all(bad for _, bad in accepted[j:j + 3]))
    assert any(not ok for _, ok, _, _ in watch.probes)  # refused ones came, and did not count
    worse = [k for k, s in enumerate(watch.statuses) if s & Status.MODEL_WORSE]
    assert worse, "the guard never tripped"
    first = worse[0]
    assert first == third, (first, watch.probes[:8])
    assert all(watch.statuses[k] & Status.ALARM for k in worse)
    assert worse == list(range(first, len(watch.statuses)))  # latched
    # the cause from the trip on is the guard's, never "inputs invalid"
    assert set(watch.causes[first:]) == {Cause.MODEL_WORSE_THAN_NONE}
    offsets = watch.offsets
    assert abs(offsets[first - 1]) > 2.0  # the wrong model had pushed the tool off
    # held, then ramped to zero at no more than the slew limit per cycle (1 s)
    steps = [abs(b - a) for a, b in zip(offsets[first - 1:], offsets[first:], strict=False)]
    assert max(steps) <= SLEW_UM_S * cfg.raw.machine.period_s * (1 + 1e-9), max(steps)
    assert offsets[-1] == 0.0
    reached = next(k for k in range(first, len(offsets)) if offsets[k] == 0.0)
    assert reached - first >= HOLD_S  # held before the ramp
    # the log's hold and ramp name the guard as their reason
    faults = {e: f for _, e, f in log.events if e in ("fault_hold", "fault_ramp_to_zero")}
    assert faults["fault_hold"]["reason"] == "model_worse_than_none"
    assert faults["fault_ramp_to_zero"]["reason"] == "model_worse_than_none"
    assert "invalid_for_s" not in faults["fault_ramp_to_zero"]
    # every face: healthy before, unhealthy naming the guard while held and ramping
    # (the state directory's age of the last complete cycle is on this fake clock, not
    # the host's: only its cause is judged here, and it comes first)
    (url_ok, dir_ok, line_ok) = seen["before"]
    assert url_ok[0] == 0, url_ok
    assert "not in force" not in dir_ok[1], dir_ok
    assert ": on - " in line_ok
    for when in ("hold", "ramp"):
        (by_url, by_dir, line) = seen[when]
        assert by_url[0] == 1 and "model_worse_than_none" in by_url[1], (when, by_url)
        assert by_dir[0] == 1 and "model_worse_than_none" in by_dir[1], (when, by_dir)
        assert "worse than none" in line and "inputs invalid" not in line, (when, line)
        assert "3 accepted probes in a row" in line, line
    assert ": holding - " in seen["hold"][2] and ": ramping - " in seen["ramp"][2]
    print(f"model worse than none: tripped at cycle {first} (first probes at "
          f"{[k for k, _, _, _ in watch.probes[:8]]}), offset "
          f"{offsets[first - 1]:.2f} µm ramped to 0 by cycle {reached}, largest step "
          f"{max(steps):.3f} µm; while ramping: {seen['ramp'][0][1]} | {seen['ramp'][2]}")


# -- the guard alone (compd.core.adaptation), sans I/O --------------------------------------

def _stage(window: int = 3) -> ProbeStage:
    return ProbeStage(AdaptationSettings("shadow", "residual", AdaptationParams(),
                                         guard_window=window), 1)


def _probe(stage: ProbeStage, counter: float, value_um: float, offset_um: float,
           events: list[Event]) -> None:
    stage.step(60.0, ProbeReading(value_um, counter), complete=True, model_um=offset_um,
               terms_um=[offset_um], offset_in_force_um=offset_um, events=events)


def test_a_right_model_with_noisy_probes_and_a_chip_never_trips_the_guard() -> None:
    rng = random.Random(3)
    stage = _stage()
    events: list[Event] = []
    for k in range(200):  # growth 30 µm, compensated to within the probe's noise
        value = rng.gauss(0.0, 0.5) + (50.0 if k in (40, 41) else 0.0)  # two chips
        _probe(stage, float(k), value, 30.0, events)
    assert not stage.model_worse
    assert "model_worse_than_none" not in [e.name for e in events]


def test_three_accepted_probes_in_a_row_worse_than_none_trip_it_and_it_stays_tripped() -> None:
    stage = _stage()
    events: list[Event] = []
    _probe(stage, 0.0, 0.0, 0.0, events)  # the baseline
    # growth +4 µm, the offset -6: the tool is 10 µm off instead of 4; each probe is
    # within the estimator's gate (it accepts them: they are evidence)
    for k in range(1, 3):
        _probe(stage, float(k), 10.0, -6.0, events)
        assert not stage.model_worse and stage.guard_worse == k
    _probe(stage, 3.0, 10.0, -6.0, events)
    assert stage.model_worse and stage.accepted == 3 and stage.refused == 0
    tripped = [e for e in events if e.name == "model_worse_than_none"]
    assert len(tripped) == 1 and tripped[0].fields["error_with_um"] == 10.0
    assert tripped[0].fields["accepted_probes"] == 3 and tripped[0].fields["refused_probes"] == 0
    _probe(stage, 4.0, 0.0, 0.0, events)  # a right probe later does not clear it
    again = ProbeStage(stage.settings, 1, stage.export_state())  # nor does a restart
    assert stage.model_worse and again.model_worse


def test_probes_the_estimator_refused_are_no_evidence() -> None:
    """-25 µm at a 30 µm offset (the tool 25 µm off with it, 5 µm without) is an
    outlier the gate refuses, and too far for the estimator to re-acquire (beyond
    max_total_um): three of them, or thirty, never trip the guard, whatever a
    broken or writable probe source sends; they are counted apart. Accepted probes
    that show the same still trip it."""
    stage = _stage()
    events: list[Event] = []
    _probe(stage, 0.0, 0.0, 30.0, events)  # the baseline
    for k in range(1, 31):
        _probe(stage, float(k), -25.0, 30.0, events)
        assert stage.last is not None and stage.last["reason"] == "gate"
    assert not stage.model_worse and stage.guard == [] and stage.guard_worse == 0
    assert stage.refused == 30 and stage.accepted == 0
    assert "model_worse_than_none" not in [e.name for e in events]
    assert not ProbeStage(stage.settings, 1, stage.export_state()).model_worse
    # refused probes between accepted ones neither count nor break the run
    for k in range(31, 34):
        _probe(stage, float(k), 10.0, -6.0, events)
        if k < 33:
            _probe(stage, k + 0.5, -25.0 - 40.0, 30.0, events)  # an outlier in between
    assert stage.model_worse
    [tripped] = [e for e in events if e.name == "model_worse_than_none"]
    assert tripped.fields["accepted_probes"] == 3 and tripped.fields["refused_probes"] == 2


def test_a_long_run_of_refused_probes_says_the_model_or_the_probe_is_wrong() -> None:
    """Refused probes switch nothing off, but they are not silent: DISAGREE_AFTER
    gate refusals in a row raise "probes_disagree" once, the page says so, and an
    accepted probe ends the run."""
    stage = _stage()
    events: list[Event] = []
    _probe(stage, 0.0, 0.0, 30.0, events)  # the baseline
    for k in range(1, 3 * DISAGREE_AFTER):
        _probe(stage, float(k), -25.0, 30.0, events)
    assert stage.gate_refusals == 3 * DISAGREE_AFTER - 1 and not stage.model_worse
    [warned] = [e for e in events if e.name == "probes_disagree"]
    assert warned.fields["gate_refusals"] == DISAGREE_AFTER
    view = AdaptationView(0.0, 1.0, 0.0, False, False, gate_refusals=stage.gate_refusals)
    word, why = operator_state(FaultState.OK, Cause.IN_FORCE, {}, adaptation=view)
    assert word == "on" and "the model or the probe source is wrong" in why
    _probe(stage, 100.0, 0.0, 30.0, events)  # agrees again
    assert stage.gate_refusals == 0
    view = AdaptationView(0.0, 1.0, 0.0, False, False, gate_refusals=stage.gate_refusals)
    assert "probe source" not in operator_state(FaultState.OK, Cause.IN_FORCE, {},
                                                adaptation=view)[1]


def test_a_guard_from_an_older_checkpoint_keeps_its_latch_not_its_judgements() -> None:
    """An older compd judged refused probes too: a restored partial window may hold
    their verdicts, so it starts afresh; a latched trip stays (recalibrate)."""
    stage = _stage()
    state = stage.export_state()
    del state["guard_accepted_only"]
    state["guard"] = [True, True]
    assert ProbeStage(stage.settings, 1, state).guard == []
    state["model_worse"] = True
    assert ProbeStage(stage.settings, 1, state).model_worse
    current = stage.export_state()
    current["guard"] = [True, True]
    assert ProbeStage(stage.settings, 1, current).guard == [True, True]


def test_guard_window_0_is_no_guard() -> None:
    stage = _stage(0)
    events: list[Event] = []
    for k in range(10):
        _probe(stage, float(k), 30.0, -20.0, events)
    assert not stage.model_worse
