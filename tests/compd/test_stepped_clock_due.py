"""`SteppedClock.due`: how many sleepers a move of the clock wakes (what
`tests.harness.Fleetstep` waits for when several daemons share one clock)."""

from __future__ import annotations

import asyncio

from compd.testing import SteppedClock


async def test_due_counts_the_sleepers_a_tick_or_a_move_would_wake() -> None:
    clock = SteppedClock(period_s=1.0)
    assert clock.due() == 0
    naps = [asyncio.ensure_future(clock.sleep(s)) for s in (1.0, 1.0, 2.5)]
    await clock.cycle_done(3)
    assert clock.due() == 2            # the next tick (t = 1) ends the two 1 s naps
    assert clock.due(2.5) == 3 and clock.due(0.5) == 0
    clock.tick()
    await asyncio.gather(*naps[:2])
    assert clock.due() == 0 and clock.due(3.0) == 1  # ended sleeps are not counted
    clock.advance(2.0)
    await naps[2]
    assert clock.sleeping == 0 and clock.due(100.0) == 0
