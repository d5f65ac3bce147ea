"""A link loss with a reconnect slower than the daemon's cycle (a safety defect: a
daemon that never reconnects holds a frozen offset while the machine drifts).

The daemon bounds each cycle's read by max(real period, 2·timeout_s)
(`compd.runtime.cycle_io`); a reconnect runs inside a read. When the connect
takes longer than that bound (an OPC UA secure channel and session are several
round trips, each well inside timeout_s), the read's deadline must not cancel
the connect: it goes on in its own task bounded by connect_timeout_s
(`drivers.link.Link`), the reads in the meantime fail (the cycle holds), and a
cycle after it completes compensates again, ramping at the slew limit.

Rig: the real driver through `FaultProxy` to the simulated controller, the
daemon on its real clock (`DaemonRig(stepped=False)`): the read's deadline, the
connect's and the reconnect backoff are real seconds, and a stepped clock would
run the failing cycles back to back far faster than any of them (hundreds of
machine seconds held, then ramped, within one connect). The assertions are on
cycles and on what the daemon wrote, never on wall-clock times.

After the daemon compensates, the proxy resets every connection (the
controller restarted) and from then on holds each of a new connection's first
client -> server chunks `HOLD_S` longer (`FaultProxy.slow_start`): the OPC UA
handshake (hello, secure channel, session, activation, the outputs'
types: 5 requests) takes ≥ 5·HOLD_S = 1.5 × the read bound, each of its
requests still inside timeout_s. Modbus has no handshake (its connect is the TCP
one): its first request after the reconnect is the held one.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import pytest

from compd.core.output import Status
from drivers.sim.registry import make_sim_controller
from tests.configs import make_config
from tests.faults.daemon_rig import DaemonRig
from tests.faults.frames import FRAME_LENGTH
from tests.faults.invariants import Invariants, invariants
from tests.faults.proxy import FaultProxy

__all__ = ["invariants"]  # the autouse fixture, imported to be active here

#: machine seconds per real second: one machine second (the period) is 0.4 s real
SCALE = 2.5
REAL_PERIOD_S = 1.0 / SCALE
TIMEOUT_S = 0.5 * REAL_PERIOD_S
#: the daemon's bound on one cycle's read (`CycleIO._read`)
READ_LIMIT_S = max(REAL_PERIOD_S, 2 * TIMEOUT_S)
#: the extra hold on each handshake request: inside timeout_s with room for a busy server
HOLD_S = 0.6 * TIMEOUT_S
#: client -> server chunks of a new connection that are held
HELD_CHUNKS = {"opcua": 5, "modbus": 1}
SLEW = 4.0
#: the compensation must resume within this many cycles of the link loss (real
#: seconds, generous for a busy machine: the backoff is capped at 0.4 s)
RESUME_WITHIN = 40


def _endpoint(sim_endpoint: str, proxy: FaultProxy) -> str:
    return urlsplit(sim_endpoint)._replace(netloc=f"{proxy.host}:{proxy.port}").geturl()


@pytest.mark.parametrize("protocol", ["opcua", "modbus"])
async def test_slow_reconnect_after_link_loss_resumes(protocol: str, tmp_path: Path,
                                                      invariants: Invariants) -> None:
    assert HELD_CHUNKS["opcua"] * HOLD_S > READ_LIMIT_S  # the connect outlasts a read
    sim: Any = make_sim_controller(protocol)
    await sim.start()
    parts = urlsplit(sim.endpoint)
    assert parts.hostname is not None and parts.port is not None
    proxy = FaultProxy(parts.hostname, parts.port, frame_length=FRAME_LENGTH[protocol])
    await proxy.start()
    try:
        await sim.publish({"bearing": 20.0, "ambient": 20.0})
        cfg = make_config(sim, tmp_path, time_scale=SCALE, slew_um_s=SLEW, overrides={
            "controller": {"endpoint": _endpoint(sim.endpoint, proxy), "timeout_s": TIMEOUT_S,
                           "connect_timeout_s": 5.0,
                           "backoff": {"initial_s": 0.05, "cap_s": 0.4}}})

        async def plant(index: int, _t: float) -> None:
            await sim.publish({"bearing": 22.0 if index >= 3 else 20.0, "ambient": 20.0})

        rig = DaemonRig(sim, cfg, invariants, plant)
        io = rig.daemon.io
        await rig.start()
        try:
            # the bearing heated at cycle 3: compensating (the offset ramping) from then
            await rig.until(lambda: rig.daemon.loop.cycles >= 6 and io.read_ok is True)
            lost_at = rig.daemon.loop.cycles
            proxy.reset()  # the controller restarted: every connection is gone
            await rig.until(lambda: io.read_ok is False)
            proxy.slow_start(HOLD_S, HELD_CHUNKS[protocol])  # and it answers slowly
            failed_at = rig.daemon.loop.cycles
            await rig.until(lambda: io.read_ok is True
                            or rig.daemon.loop.cycles > failed_at + RESUME_WITHIN)
            resumed_at = rig.daemon.loop.cycles
            # a few complete cycles after the reconnect: compensating again
            await rig.until(lambda: rig.daemon.loop.cycles >= resumed_at + 5)
        finally:
            assert await rig.stop() == 0
    finally:
        await proxy.stop()
        await sim.stop()
    assert io.read_ok is True, (
        f"no read within {RESUME_WITHIN} cycles after the link loss: the daemon never "
        f"reconnected ({proxy.connections_accepted} connections accepted)")
    # the cycles as the daemon planned them (the loop's counters race the test's polls)
    log = invariants.log()
    first_held = next(i for i in range(lost_at - 1, len(log))
                      if log[i].result.status & Status.HOLDING)
    resumed = next(i for i in range(first_held, len(log))
                   if not log[i].result.status & Status.HOLDING)
    print(f"{protocol}: link lost after cycle {lost_at}; held {resumed - first_held} cycles "
          f"of {REAL_PERIOD_S} s (connect ≥ {HELD_CHUNKS[protocol] * HOLD_S:.2f} s, read "
          f"bound {READ_LIMIT_S} s); connections {proxy.connections_accepted - 1} after the "
          f"first")
    # one handshake, gone on through the cycles that gave up on it (a second one at
    # most: an attempt the backoff allowed before the proxy slowed down); cancelled
    # by every cycle's deadline, there were 4 to 26 here, each one lost
    assert proxy.connections_accepted - 1 <= 2, "each cycle started the handshake again"
    held = [c.result for c in log[first_held:resumed]]
    before = log[lost_at - 1].result.stage_um
    assert all(r.stage_um == pytest.approx(before, abs=1e-9) for r in held)
    assert all(c.result.status & Status.OK for c in log[resumed:])
    # never a jump: every step within R·Δt (the invariants check each write too)
    for prev, cur in zip(log[lost_at - 1:], log[lost_at:], strict=False):
        assert abs(cur.result.stage_um - prev.result.stage_um) <= \
            SLEW * min(cur.now_s - prev.now_s, 2.0) + 1e-6
