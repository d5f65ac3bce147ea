"""A failed sensor with a fallback model, end to end: the in-process daemon on the
stepped clock against the real simulated Modbus controller, every write checked
by the output invariants (|u| ≤ limit, |Δu| ≤ slew·Δt against what the controller
holds, heartbeat).

The model file is SP2 with a ``[[fallback]]`` for each of its inputs. The
ambient's Pt100 opens at the controller (its analog card's sentinel 32767):
the fallback without the ambient takes over at that sample (degraded, not an
alarm: the status word says OK, neither HOLDING nor ALARM; the status page says
``degraded``; ``compd_fallback_in_force{lost="ambient"}`` is 1; ``compd health``
passes with a warning), the difference between the two models ramps in at the
slew limit, and it stays in force past hold_s (no hold, no ramp to zero). The
sensor back, the main model is in force again, ramped. Then the bearing's
Pt100 shorts (-32768): the fallback on the ambient alone takes over, ramped.
"""

from __future__ import annotations

import asyncio
import json
import urllib.request
from itertools import pairwise
from pathlib import Path
from typing import Any

import pytest

from compd.cli import main as cli
from compd.core.health import Cause
from compd.core.output import Status
from compd.core.plan import Row
from drivers.sim.modbus_server import CHANNELS, ModbusSimController
from drivers.sim.ports import free_tcp_port
from tests.compd.core.fallback_helpers import SP2_MAIN
from tests.configs import make_config
from tests.faults.daemon_rig import DaemonRig
from tests.faults.invariants import Invariants, invariants

__all__ = ["invariants"]  # the autouse fixture, imported to be active here

SLEW = 2.0
HOLD_S = 10.0
REF = {"bearing": 20.0, "ambient": 20.0}

#: SP2 as the library has it (17.6 µm/K of bearing), and a fallback for each input:
#: without the ambient, a first-order spindle term of 22 µm/K (the fit's gain on
#: the bearing alone differs from the main model's); without the bearing, -5 µm/K
#: of ambient
MODEL = SP2_MAIN + """
[[fallback]]
lost = "ambient"
model = { name = "without ambient", period_s = 1.0 }
[[fallback.terms]]
name = "spindle"
inputs = { bearing = 1.0 }
a = ["0.22", "0"]
b = ["1", "-0.99"]

[[fallback]]
lost = "bearing"
model = { name = "without bearing", period_s = 1.0 }
[[fallback.terms]]
name = "ambient"
inputs = { ambient = 1.0 }
a = ["-0.05", "0"]
b = ["1", "-0.99"]
"""

OPEN, SHORT = 32767, -32768  # the analog card's Pt100 sentinels (int16, 0.1 °C per count)


def _offset(rig: DaemonRig) -> float:
    r = rig.daemon.loop.last_result
    return r.stage_um if r is not None else float("nan")


def _cause(rig: DaemonRig) -> Cause | None:
    r = rig.daemon.loop.last_result
    return r.cause if r is not None else None


def _settled(rig: DaemonRig) -> bool:
    r = rig.daemon.loop.last_result
    return r is not None and r.model_um is not None and abs(r.stage_um - r.model_um) < 0.05


def _steps(inv: Invariants, since: int = 0) -> list[float]:
    """The changes of the written offset between two cycles (µm), from cycle `since`."""
    sent = [c.written["offset"] for c in inv.log()[since:] if "offset" in c.written]
    return [abs(b - a) for a, b in pairwise(sent)]


def _get(url: str) -> str:
    with urllib.request.urlopen(url, timeout=10.0) as resp:
        return str(resp.read().decode("utf-8"))


def _fallback_metric(metrics: str) -> dict[str, float]:
    """``compd_fallback_in_force`` by its ``lost`` label."""
    out: dict[str, float] = {}
    for line in metrics.splitlines():
        if line.startswith('compd_fallback_in_force{lost="'):
            label, _, value = line[len('compd_fallback_in_force{lost="'):].partition('"} ')
            out[label] = float(value)
    return out


async def test_sensor_lost_degraded_fallback_ramped_and_back_to_the_main_model(
        tmp_path: Path, invariants: Invariants, capsys: pytest.CaptureFixture[str]) -> None:
    model = tmp_path / "sp2_fallbacks.toml"
    model.write_text(MODEL, encoding="utf-8")
    port = free_tcp_port("127.0.0.1")
    url = f"http://127.0.0.1:{port}/"
    sim = ModbusSimController()
    await sim.start()
    inputs: dict[str, float] = {"bearing": 21.0, "ambient": 20.0}
    raw: dict[str, int] = {}  # a channel's register held at a sentinel
    await sim.publish(inputs)
    overrides: dict[str, Any] = {"model": {"reference": REF}, "faults": {"hold_s": HOLD_S},
                                 "telemetry": {"metrics_port": port},
                                 "faces": {"http": {"enabled": True}}}
    cfg = make_config(sim, tmp_path, time_scale=1.0, slew_um_s=SLEW, model=str(model),
                      overrides=overrides)
    assert sorted(cfg.model.fallbacks) == ["ambient", "bearing"]

    async def plant(_index: int, _t: float) -> None:
        await sim.publish({k: v for k, v in inputs.items() if k not in raw})
        for name, words in raw.items():
            sim.set_raw("input", CHANNELS[name].address, [words])

    rig = DaemonRig(sim, cfg, invariants, plant, stepped=True)
    await rig.start()
    try:
        # warm at start, the calibration reference: the main model's 17.6 µm, ramped in
        await rig.until(lambda: _cause(rig) is Cause.IN_FORCE and _settled(rig))
        main_um = _offset(rig)
        assert abs(main_um - 17.6) < 0.3
        assert json.loads(await asyncio.to_thread(_get, url + "status.json"))["state"] == "on"

        # the ambient's Pt100 opens: the fallback without it, at that very sample
        since = len(invariants.log())
        raw["ambient"] = OPEN
        await rig.until(lambda: rig.daemon.loop.last_result is not None
                        and rig.daemon.loop.last_result.validity.get("ambient") is not None)
        first = rig.daemon.loop.last_result
        assert first is not None and first.cause is Cause.DEGRADED
        assert first.snapshot.fallback_for == "ambient"
        assert first.model_um is not None and abs(first.model_um - 22.0) < 0.3
        assert first.model_um - main_um > 2.0 * SLEW  # a step the output stage must ramp
        assert "fallback_in_force" in rig.log.names()
        n = rig.daemon.loop.cycles
        await rig.until(lambda: rig.daemon.loop.cycles >= n + int(3 * HOLD_S))  # well past hold_s
        r = rig.daemon.loop.last_result
        assert r is not None and r.cause is Cause.DEGRADED and r.healthy and r.in_force
        assert abs(r.stage_um - 22.0) < 0.3  # the fallback's offset is in force
        degraded = invariants.log()[since:]
        assert all(c.result.cause is Cause.DEGRADED for c in degraded)
        assert all(c.result.status & Status.OK for c in degraded)
        assert not any(c.result.status & (Status.HOLDING | Status.RAMPING | Status.ALARM)
                       for c in degraded)
        steps = _steps(invariants, since - 1)
        assert max(steps) <= SLEW * 1.0 + 1e-3 and max(steps) > SLEW - 1e-3  # ramped
        status = int((await sim.outputs())["status"])
        assert status & Status.OK and not status & (Status.HOLDING | Status.ALARM)
        assert not {"fault_hold", "fault_ramp_to_zero"} & set(rig.log.names())
        page = json.loads(await asyncio.to_thread(_get, url + "status.json"))
        assert page["state"] == "degraded" and page["cause"] == "degraded"
        assert page["fallback_for"] == "ambient" and page["healthy"] is True
        assert "fallback model" in page["why"]
        ambient = next(c for c in page["channels"] if c["name"] == "ambient")
        assert ambient["valid"] is False
        metrics = await asyncio.to_thread(_get, url + "metrics")
        assert _fallback_metric(metrics) == {"ambient": 1.0}
        assert await asyncio.to_thread(
            cli, ["health", "--url", url, "--max-age-s", "600"]) == 0
        out = capsys.readouterr().out
        assert "degraded, fallback model without ambient in force" in out

        # the sensor is back: the main model again, the difference ramped out
        since = len(invariants.log())
        del raw["ambient"]
        await rig.until(lambda: _cause(rig) is Cause.IN_FORCE and _settled(rig))
        assert "fallback_ended" in rig.log.names()
        back = invariants.log()[since:]
        row = back[0].result
        assert isinstance(row, Row) and row.snapshot.fallback_for is None
        assert abs(_offset(rig) - main_um) < 0.3
        steps = _steps(invariants, since - 1)
        assert max(steps) <= SLEW * 1.0 + 1e-3 and max(steps) > SLEW - 1e-3  # ramped
        page = json.loads(await asyncio.to_thread(_get, url + "status.json"))
        assert page["state"] == "on" and page["fallback_for"] is None
        metrics = await asyncio.to_thread(_get, url + "metrics")
        assert _fallback_metric(metrics) == {"ambient": 0.0}

        # the bearing's Pt100 shorts: the fallback on the ambient alone, ramped down
        since = len(invariants.log())
        raw["bearing"] = SHORT
        await rig.until(lambda: _cause(rig) is Cause.DEGRADED and _settled(rig))
        r = rig.daemon.loop.last_result
        assert r is not None and r.snapshot.fallback_for == "bearing"
        assert abs(r.stage_um) < 0.3  # the ambient at its reference: no growth
        assert all(c.result.cause is Cause.DEGRADED for c in invariants.log()[since:])
        steps = _steps(invariants, since - 1)
        assert max(steps) <= SLEW * 1.0 + 1e-3
        assert len(steps) >= int(main_um / SLEW)  # 17.6 µm to 0 took that many cycles
        metrics = await asyncio.to_thread(_get, url + "metrics")
        assert _fallback_metric(metrics)["bearing"] == 1.0
    finally:
        assert await rig.stop() == 0
        await sim.stop()
    assert not invariants.violations
