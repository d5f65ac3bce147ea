"""Wall-clock jumps of ±1 h: the daemon runs in-process against a
simulated controller and the wall clock jumps by ±3600 s mid-run, for the
whole process: the daemon's own wall clock (given to it, as its default
`time.time` is bound when the module loads) and `time.time` for the drivers
and the sims. Scheduling uses the monotonic clock only, here a
`compd.testing.SteppedClock` moved to each next deadline as soon as the daemon
sleeps (a busy machine makes the test slower, never red), so the figure is
exactly 60 cycles per 60 machine seconds around the jump: a scheduler on the
wall clock would burst (catch up an hour) or stall after it.

Stale inputs: the channel check compares source timestamps with the wall
clock. Against OPC UA the timestamps are the controller's (the sim stamps
them with `datetime.now`, which the patch does not move): a jump of the
daemon's clock against the controller's is what NTP or an operator does in
the field, and must not make a channel 'stale' (that would hold, then ramp
the compensation away). Against Modbus the timestamps come from the
daemon's own (jumping) clock. Both must stay valid on every cycle.
"""

from __future__ import annotations

import itertools
import time
from pathlib import Path

import pytest

from compd.core.plan import Row
from compd.core.validation import ChannelLimits, Validator
from drivers.base import Sample
from drivers.sim.registry import make_sim_controller
from tests.configs import make_config
from tests.faults.daemon_rig import DaemonRig
from tests.faults.invariants import Invariants, invariants

__all__ = ["invariants"]  # the autouse fixture, imported to be active here

JUMP_AT_S = 40.0  # machine seconds
WINDOW_S = 60.0


class JumpingWallClock:
    """time.time() plus a jump that the test sets."""

    def __init__(self) -> None:
        self.real = time.time
        self.jump_s = 0.0

    def __call__(self) -> float:
        return self.real() + self.jump_s


@pytest.mark.parametrize("jump_s", [3600.0, -3600.0], ids=["+1h", "-1h"])
@pytest.mark.parametrize("protocol", ["modbus", "opcua"])
async def test_wall_clock_jump(protocol: str, jump_s: float, tmp_path: Path,
                               invariants: Invariants,
                               monkeypatch: pytest.MonkeyPatch) -> None:
    # time scale 1: the stepped clock runs the cycles as fast as the machine allows
    # whatever the scale, and at 1 the driver's timeout (0.45 of a real period) and
    # the staleness limit (60 s real) are far from what a loaded machine's stalls
    # reach; a 1 h step is far beyond either
    clock = JumpingWallClock()
    sim = make_sim_controller(protocol)
    await sim.start()
    try:
        await sim.publish({"bearing": 20.0, "ambient": 20.0})
        stale = {"stale_after_s": 60.0}
        cfg = make_config(sim, tmp_path, time_scale=1.0, slew_um_s=4.0, overrides={
            "channels": {"bearing": stale, "ambient": stale}})
        jumped_at: list[float] = []

        async def plant(index: int, t: float) -> None:
            await sim.publish({"bearing": 22.0 if index >= 3 else 20.0, "ambient": 20.0})
            if t >= JUMP_AT_S and not jumped_at:
                clock.jump_s = jump_s
                jumped_at.append(t)

        monkeypatch.setattr(time, "time", clock)
        rig = DaemonRig(sim, cfg, invariants, plant, stepped=True, wall=clock)
        end_s = JUMP_AT_S + WINDOW_S / 2 + 2.0
        assert await rig.run_until(
            lambda: rig.machine_s > end_s, limit_s=120.0) == 0
    finally:
        await sim.stop()
    log = invariants.log()
    assert jumped_at and clock.jump_s == jump_s
    records = [c.result.record for c in log if isinstance(c.result, Row)]
    # the daemon's wall clock jumped (its rows are stamped with it) between two cycles
    steps = [b.wall_s - a.wall_s for a, b in itertools.pairwise(records)]
    assert any(abs(step - jump_s) < 60.0 for step in steps), "the daemon's wall did not jump"
    t_jump = next(c.now_s for c in log if c.now_s >= jumped_at[0] - 1.0)
    lo, hi = t_jump - WINDOW_S / 2, t_jump + WINDOW_S / 2
    window = [c.now_s for c in log if lo <= c.now_s < hi]
    # the jump must not make a channel stale (a read that times out on a loaded
    # test machine is another fault, with its own tests)
    invalid = [(round(r.mono_s, 2), r.validity) for r in records
               if r.mono_s > 10.0  # after the +2 K step's rate holds
               and any(v == "stale" for v in r.validity.values())]
    print(f"{protocol} jump {jump_s:+.0f} s: {len(window)} cycles in the 60 s around the "
          f"jump; {len(invalid)} cycles with a stale channel")
    assert len(window) == 60
    spans = [b - a for a, b in itertools.pairwise(window)]
    assert min(spans) == pytest.approx(cfg.period_s) == max(spans)  # no burst, no stall
    assert "cycle_overrun" not in rig.log.names()
    assert not invalid, invalid[:3]
    assert log[-1].result.state == "ok"


def test_validator_ignores_wall_clock_steps() -> None:
    """The pure check: the caller's wall clock steps ±1 h (source timestamps
    from the controller's clock, which does not), or the source clock steps
    (a controller set back an hour): never 'stale'. A frozen timestamp, a
    small step back and an old timestamp at start still are."""
    lim = {"t": ChannelLimits(-20.0, 150.0, stale_after_s=10.0)}
    for jump in (3600.0, -3600.0):
        v = Validator(lim, time_scale=10.0)
        for k in range(100):
            now_s = float(k)  # machine s; real s = now_s / 10
            ts = 1000.0 + now_s / 10.0
            wall = ts + 0.05 + (jump if k >= 50 else 0.0)
            assert v.check(now_s, {"t": Sample(20.0, ts)}, wall_s=wall)["t"] is None, (jump, k)
        # the controller's clock set back (and forward) an hour instead
        v = Validator(lim, time_scale=10.0)
        for k in range(100):
            now_s = float(k)
            wall = 1000.0 + now_s / 10.0
            ts = wall - 0.05 + (-jump if k >= 50 else 0.0)
            assert v.check(now_s, {"t": Sample(20.0, ts)}, wall_s=wall)["t"] is None, (jump, k)
    # still stale: frozen for > stale_after_s machine seconds after a jump
    v = Validator(lim, time_scale=10.0)
    reasons = [v.check(float(k), {"t": Sample(20.0, 1000.0 + min(k, 60) / 10.0)},
                       wall_s=1000.0 + k / 10.0 + (3600.0 if k >= 50 else 0.0))["t"]
               for k in range(100)]
    assert reasons[65] is None and reasons[-1] == "stale"
