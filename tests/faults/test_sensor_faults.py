"""Sensor faults: open / shorted Pt100, a Bad OPC UA status, a
stuck sensor, a one-sample spike. Each figure is measured on the pure cycle
with a fake clock (exact) and through the wire: the in-process daemon against
a simulated controller whose memory holds the fault (Modbus, S7, OPC UA), on
a stepped clock (`DaemonRig(stepped=True)`: no cycle late, whatever the load).

The "hold-last-value reference" for an invalid channel: from the first
invalid sample the offset stays at the last value written before it, until
the channel has been invalid for hold_s; then it ramps to 0 at the slew
limit R with the alarm bit set. A run must follow that reference within
0.1 µm, and the ramp and the alarm must start at hold_s ± Ts.

Every cycle of every test also passes the invariants of `invariants.py`.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from compd.core.cycle import Cycle
from compd.core.output import Status
from compd.core.validation import ChannelLimits
from compd.testing import FakeClock
from drivers.base import Quality, Sample
from drivers.sim.modbus_server import ModbusSimController
from drivers.sim.registry import make_sim_controller
from tests.compd.core.cycle_helpers import params, samples, sp2
from tests.configs import make_config
from tests.faults.daemon_rig import DaemonRig
from tests.faults.invariants import CycleLog, Invariants, invariants, run_pure

__all__ = ["invariants"]  # the autouse fixture, imported to be active here

TOL_UM = 0.1


# -- figures from a cycle log -------------------------------------------------------


def fault_figures(log: list[CycleLog], fault_index: int, hold_s: float, slew_um_s: float,
                  period_s: float) -> dict[str, float]:
    """From the cycle at `fault_index` (the first sample carrying the fault):
    the offset's max deviation from the hold-last-value reference, and when
    the ramp and the alarm started after the fault."""
    held = log[fault_index - 1].result.stage_um
    t0 = log[fault_index].now_s
    ramp_i = next(i for i in range(fault_index, len(log))
                  if log[i].result.state == "ramp")
    alarm_i = next(i for i in range(fault_index, len(log))
                   if log[i].result.status & Status.ALARM)
    dev = 0.0
    ref = held
    for i in range(fault_index, len(log)):
        r = log[i].result
        if i >= ramp_i:
            dt = min(log[i].now_s - log[i - 1].now_s, 2.0 * period_s)
            ref = math.copysign(max(abs(ref) - slew_um_s * dt, 0.0), held)
        dev = max(dev, abs(r.stage_um - ref))
    return {"held_um": held, "max_dev_um": dev,
            "ramp_after_s": log[ramp_i].now_s - t0, "alarm_after_s": log[alarm_i].now_s - t0,
            "ramp_cycles": float(len(log) - ramp_i)}


# -- pure cycle ---------------------------------------------------------------------


OPEN_FAULTS = {
    "open_32767": Sample(3276.7, 0.0),
    "short_-32768": Sample(-3276.8, 0.0),
    "above_850": Sample(850.1, 0.0),
    "below_-200": Sample(-200.1, 0.0),
    "nan": Sample(math.nan, 0.0),
    "bad_status": Sample(25.0, 0.0, Quality.BAD),
}


@pytest.mark.parametrize("fault", sorted(OPEN_FAULTS))
def test_open_sensor_pure_holds_then_ramps(fault: str, invariants: Invariants) -> None:
    p = params(hold_s=60.0, slew_um_s=1.0)
    cycle, clock = Cycle(p, sp2()), FakeClock()
    bad = OPEN_FAULTS[fault]
    k0 = 120
    for k in range(k0 + 130):
        t = clock.tick()
        s = samples(t, 20.0 + min(k, 100) * 0.02)  # +2 K: the offset climbs ≈ 30 µm
        if k >= k0:
            s["bearing"] = Sample(bad.value, t, bad.quality)
        r = run_pure(invariants, cycle, t, s)
        if k == k0:  # invalid within one sample: the very sample that carries it
            assert r.validity["bearing"] is not None
            assert not r.inputs_valid and r.state == "hold"
    log = invariants.log(cycle)
    f = fault_figures(log, k0, p.hold_s, p.slew_um_s, p.period_s)
    assert abs(f["held_um"]) > 10.0
    assert f["max_dev_um"] <= TOL_UM, f
    assert p.hold_s - p.period_s <= f["ramp_after_s"] <= p.hold_s + p.period_s, f
    assert f["alarm_after_s"] == f["ramp_after_s"], f
    assert log[-1].result.stage_um == 0.0


def _quantised_heating(k: int, phase_s: float) -> float:
    return round(20.0 + 0.5 * (k + phase_s) / 3600.0, 1)


#: both stuck criteria, as a config with stuck_after_s = 900 s and the default
#: stuck_delta_k (2 K) gives them
STUCK: dict[str, object] = {"stuck_after_s": 900.0, "stuck_delta_k": 2.0,
                            "temperature": True}


def _stuck_channels(ambient_stuck: bool) -> dict[str, ChannelLimits]:
    """The helper's channels with a motor temperature beside them; the bearing
    and the motor with both stuck criteria, the ambient too if asked (not in a
    real config: the hall may rightly stay put while the spindle warms up)."""
    chans = dict(params().channels)
    amb: dict[str, object] = STUCK if ambient_stuck else {"temperature": True}
    chans["bearing"] = ChannelLimits(-20.0, 150.0, 0.5, 30.0, **STUCK)  # type: ignore[arg-type]
    chans["ambient"] = ChannelLimits(-10.0, 60.0, 0.5, 30.0, **amb)  # type: ignore[arg-type]
    chans["motor"] = ChannelLimits(-20.0, 150.0, 0.5, 30.0, **STUCK)  # type: ignore[arg-type]
    return chans


def test_stuck_no_false_alarm_over_8h_of_slow_quantised_heating(
        invariants: Invariants) -> None:
    """8 h, the three temperatures heating at 0.5 K/h with 0.1 K quantisation
    (a new value every 12 min, out of phase), stuck_after_s = 900 s and
    stuck_delta_k = 2 K: no channel ever invalid, never held, the heartbeat
    advances on every cycle."""
    cycle, clock = Cycle(params(channels=_stuck_channels(True)), sp2()), FakeClock()
    for k in range(8 * 3600):
        t = clock.tick()
        s = samples(t, _quantised_heating(k, 0.0), _quantised_heating(k, 360.0), speed=0.0)
        s["motor"] = Sample(_quantised_heating(k, 180.0), t)
        r = run_pure(invariants, cycle, t, s)
        if not r.inputs_valid or any(v is not None for v in r.validity.values()):
            raise AssertionError(f"false alarm at {t} s: {r.validity}")
    assert r.heartbeat == 8 * 3600


@pytest.mark.parametrize("frozen_before_s", [3600.0, 0.0])
def test_stuck_sensor_flagged_after_warm_up_starts(frozen_before_s: float,
                                                   invariants: Invariants) -> None:
    """The bearing sensor is frozen at 20.0 °C; the machine rests (nothing
    moves) for `frozen_before_s`, then warms up: the spindle starts, the motor
    temperature rises 8 K with a 15 min time constant (+2 K in about 4 min),
    the ambient +1 K/h, all in 0.1 K steps; stuck_after_s = 900 s (long enough
    for no false alarm at 0.5 K/h). Figure: seconds from the warm-up start to
    the 'stuck' flag, within 10 min (by stuck_delta_k = 2 K: the time
    criterion alone took 901 s when frozen at the warm-up start)."""
    cycle, clock = Cycle(params(channels=_stuck_channels(False)), sp2()), FakeClock()
    rest = int(frozen_before_s)
    flagged: float | None = None
    for k in range(rest + 1800):
        t = clock.tick()
        warm = max(0, k - rest)
        amb = round(20.0 + warm / 3600.0, 1)
        s = samples(t, 20.0, amb, speed=8000.0 if warm > 0 else 0.0)
        s["motor"] = Sample(round(20.0 + 8.0 * (1.0 - math.exp(-warm / 900.0)), 1), t)
        r = run_pure(invariants, cycle, t, s)
        assert r.validity["ambient"] is None and r.validity["motor"] is None
        if r.validity["bearing"] == "stuck":
            flagged = float(warm)
            break
        assert warm > 0 or r.validity["bearing"] is None  # at rest: not stuck
    assert flagged is not None
    print(f"stuck flagged {flagged:.0f} s after warm-up start "
          f"(frozen {frozen_before_s:.0f} s before)")
    assert 0.0 < flagged <= 600.0


@pytest.mark.parametrize("spike_k", [50.0, -50.0])
def test_one_sample_spike_matches_a_spike_free_run(spike_k: float,
                                                   invariants: Invariants) -> None:
    p = params()
    ref, spiked = Cycle(p, sp2()), Cycle(p, sp2())
    clock = FakeClock()
    dev = 0.0
    for k in range(1500):
        t = clock.tick()
        b = 20.0 + 4.0 * (1.0 - math.exp(-k / 600.0))  # a warm-up, ≤ 0.007 K/s
        ra = run_pure(invariants, ref, t, samples(t, b))
        rb = run_pure(invariants, spiked, t, samples(t, b + (spike_k if k == 700 else 0.0)))
        if k == 700:
            assert rb.validity["bearing"] is not None
        dev = max(dev, abs(ra.stage_um - rb.stage_um))
    print(f"spike {spike_k:+.0f} K: max |offset - spike-free| = {dev:.4f} µm")
    assert dev <= TOL_UM


# -- through the wire -------------------------------------------------------------------

HOLD_S = 20.0
SLEW = 4.0
FAULT_READ = 30


def _wire_config(sim: object, tmp_path: Path, time_scale: float,
                 hold_s: float = HOLD_S) -> object:
    return make_config(sim, tmp_path, time_scale=time_scale,  # type: ignore[arg-type]
                       slew_um_s=SLEW, overrides={"faults": {"hold_s": hold_s}})


async def _open_sensor_run(protocol: str, inject: object, tmp_path: Path,
                           inv: Invariants, time_scale: float,
                           hold_s: float = HOLD_S) -> dict[str, float]:
    sim = make_sim_controller(protocol)
    await sim.start()
    try:
        await sim.publish({"bearing": 20.0, "ambient": 20.0})
        cfg = _wire_config(sim, tmp_path, time_scale, hold_s)
        faulted = False

        async def plant(index: int, _t: float) -> None:
            nonlocal faulted
            if not faulted:  # +2 K on the bearing at read 3: the offset climbs ≈ 30 µm
                await sim.publish({"bearing": 22.0 if index >= 3 else 20.0,
                                   "ambient": 20.0})  # fresh source timestamps
            else:
                await sim.publish({"ambient": 20.0})
            if index == FAULT_READ:
                await inject(sim)  # type: ignore[operator]
                faulted = True

        rig = DaemonRig(sim, cfg, inv, plant, stepped=True)  # type: ignore[arg-type]
        ramp_cycles = 0

        def done() -> bool:
            nonlocal ramp_cycles
            r = rig.daemon.loop.last_result
            ramp_cycles += r is not None and r.state == "ramp"
            return r is not None and r.state == "ramp" and r.stage_um == 0.0

        assert await rig.run_until(done) == 0
        log = inv.log()
        # the first cycle whose sample carries the fault (the read after the injection)
        fi = FAULT_READ
        assert log[fi - 1].result.inputs_valid
        assert log[fi].result.validity["bearing"] is not None, \
            "invalid within 1 sample"
        f = fault_figures(log, fi, hold_s, SLEW, 1.0)
        f["written_offset_um"] = (await sim.outputs())["offset"]
        status = int((await sim.outputs())["status"])
        assert status & Status.ALARM and status & Status.RAMPING
        assert "fault_ramp_to_zero" in rig.log.names()
        return f
    finally:
        await sim.stop()


def _check(f: dict[str, float], hold_s: float = HOLD_S) -> None:
    print({k: round(v, 4) for k, v in f.items()})
    assert abs(f["held_um"]) > 10.0
    assert f["max_dev_um"] <= TOL_UM, f
    # hold_s ± Ts (the daemon's clock is stepped: no cycle is ever late)
    assert hold_s - 1.0 <= f["ramp_after_s"] <= hold_s + 1.0, f
    assert f["alarm_after_s"] == f["ramp_after_s"], f
    assert f["written_offset_um"] == 0.0


@pytest.mark.parametrize("raw", [32767, -32768, 9000, -2500],
                         ids=["open_32767", "short_-32768", "900C", "-250C"])
async def test_open_pt100_modbus(raw: int, tmp_path: Path, invariants: Invariants) -> None:
    async def inject(sim: ModbusSimController) -> None:
        sim.set_raw("input", 0, [raw])  # the bearing's int16 register, ×0.1 °C

    _check(await _open_sensor_run("modbus", inject, tmp_path, invariants, 1.0))


@pytest.mark.parametrize("value", [3276.7, -3276.8], ids=["open_32767", "short_-32768"])
async def test_open_pt100_s7(value: float, tmp_path: Path, invariants: Invariants) -> None:
    async def inject(sim: object) -> None:
        await sim.publish({"bearing": value})  # type: ignore[attr-defined]
        raw = await sim.read_back("bearing")  # type: ignore[attr-defined]
        assert round(raw * 10) in (32767, -32768)  # the INT sentinel in DB1

    _check(await _open_sensor_run("s7", inject, tmp_path, invariants, 1.0))


async def test_bad_status_opcua(tmp_path: Path, invariants: Invariants) -> None:
    async def inject(sim: object) -> None:
        await sim.publish_status("bearing", bad=True)  # type: ignore[attr-defined]

    _check(await _open_sensor_run("opcua", inject, tmp_path, invariants, 1.0,
                                  hold_s=10.0), hold_s=10.0)


async def _modbus_run(tmp_path: Path, inv: Invariants, plant_values: object,
                      stop: object, overrides: dict[str, object]) -> DaemonRig:
    sim = ModbusSimController()
    await sim.start()
    try:
        cfg = make_config(sim, tmp_path, time_scale=1.0, slew_um_s=SLEW,
                          overrides=overrides)

        async def plant(index: int, t: float) -> None:
            for name, value in plant_values(index, t).items():  # type: ignore[operator]
                if isinstance(value, int):
                    sim.set_raw("input", 0 if name == "bearing" else 4, [value])
                else:
                    await sim.publish({name: value})

        rig = DaemonRig(sim, cfg, inv, plant, stepped=True)
        assert await rig.run_until(lambda: bool(stop(rig))) == 0  # type: ignore[operator]
        return rig
    finally:
        await sim.stop()


async def test_stuck_sensor_modbus(tmp_path: Path, invariants: Invariants) -> None:
    """Through the wire, at a short stuck_after_s (60 s) so it fits in a second:
    the bearing's register never changes; the machine rests 90 s, then warms
    up (ambient +0.1 K every 10 s). The bearing is flagged stuck within 10 min
    of the warm-up start (in fact stuck_after_s after the first change of
    another channel; the ambient's 2 K, the heat criterion, would take 200 s)."""
    warm_s = 90.0

    def values(_i: int, t: float) -> dict[str, float]:
        return {"bearing": 20.0,
                "ambient": round(20.0 + max(0.0, t - warm_s) * 0.01, 1)}

    def stuck(rig: DaemonRig) -> bool:
        r = rig.daemon.loop.last_result
        return r is not None and r.record is not None \
            and r.validity["bearing"] == "stuck"

    rig = await _modbus_run(tmp_path, invariants, values, stuck, {
        "channels": {"bearing": {"stuck_after_s": 60.0},
                     "ambient": {"stuck_after_s": 60.0}}})
    log = invariants.log()
    first = next(c for c in log if c.result.validity["bearing"] == "stuck")
    after = first.now_s - warm_s
    print(f"wire: stuck flagged {after:.1f} s after warm-up start")
    assert 0.0 <= after <= 600.0
    assert all(c.result.validity["bearing"] is None
               for c in log if c.now_s < warm_s)  # no false alarm while at rest
    assert rig.daemon.loop.last_result is not None and rig.daemon.loop.last_result.state == "hold"


@pytest.mark.parametrize("spike_k", [50.0, -50.0])
async def test_spike_modbus(spike_k: float, tmp_path: Path, invariants: Invariants) -> None:
    """Through the wire: the bearing steps +2 K, the offset settles; one sample
    of ±50 K (raw register); the offset matches the spike-free steady value
    (a spike-free run's offset here) within 0.1 µm on every cycle."""
    spike_read = 40

    def values(i: int, _t: float) -> dict[str, float]:
        b = (22.0 if i >= 3 else 20.0) + (spike_k if i == spike_read else 0.0)
        return {"bearing": round(b * 10), "ambient": 20.0}  # an int: a raw register

    await _modbus_run(tmp_path, invariants, values,
                      lambda rig: rig.daemon.loop.cycles >= spike_read + 10, {})
    log = invariants.log()
    assert log[spike_read].result.validity["bearing"] is not None
    before = log[spike_read - 1].result.stage_um
    dev = max(abs(c.result.stage_um - before) for c in log[spike_read:])
    print(f"wire: spike {spike_k:+.0f} K: max |offset - spike-free| = {dev:.4f} µm "
          f"(offset {before:.3f} µm)")
    assert abs(before) > 10.0 and dev <= TOL_UM
