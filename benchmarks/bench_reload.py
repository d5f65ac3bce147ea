"""SIGHUP reloads of `compd run` against the simulated Modbus controller: the
cycles missed (overruns: deadlines skipped) while the config is re-read and
a changed model (sp2 <-> sp3, alternating) is swapped in, against the same
daemon running the same number of cycles without a reload (the peer, same run).

    .venv/bin/python benchmarks/bench_reload.py [--reloads 50] [--time-scale 50]

Target: 0 cycles missed.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import signal
import sys
import tempfile
from collections.abc import Awaitable, Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from drivers.sim.modbus_server import ModbusSimController  # noqa: E402
from tests.configs import write_config  # noqa: E402


async def _heartbeat(sim: ModbusSimController) -> float:
    return float((await sim.outputs())["heartbeat"])


async def _poll(done: Callable[[], Awaitable[bool]], limit_s: float = 60.0) -> None:
    for _ in range(int(limit_s / 0.005)):
        if await done():
            return
        await asyncio.sleep(0.005)
    raise TimeoutError("the daemon never got there")


async def _at_least(sim: ModbusSimController, beat: int) -> bool:
    return await _heartbeat(sim) >= beat


async def _reloaded(log: Path, n: int) -> bool:
    text = await asyncio.to_thread(log.read_text)
    return text.count('"reload_succeeded"') >= n


async def _daemon(time_scale: float, reloads: int, peer_cycles: int) -> dict[str, float]:
    """Run `compd run` against a fresh simulated controller: `reloads` SIGHUPs
    (each waiting for its reload_succeeded), or, with reloads 0, until the
    heartbeat reaches `peer_cycles`. Returns the daemon's own daemon_stopped."""
    sim = ModbusSimController()
    await sim.start()
    await sim.publish({"bearing": 20.0, "ambient": 20.0})
    tmp = Path(tempfile.mkdtemp(prefix="compd-bench-reload-"))
    config = write_config(tmp, sim.endpoint, time_scale=time_scale)
    log = tmp / "daemon.log"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("NOTIFY_SOCKET", None)
    with log.open("ab") as f:
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "compd", "run", str(config), stdout=asyncio.subprocess.DEVNULL,
            stderr=f, env=env, cwd=str(ROOT))
    try:
        await _poll(lambda: _at_least(sim, 3))
        await sim.publish({"bearing": 24.0})  # the offset moves during the reloads
        for i in range(reloads):
            text = config.read_text()
            a, b = ('"sp2"', '"sp3"') if i % 2 == 0 else ('"sp3"', '"sp2"')
            config.write_text(text.replace(a, b))
            proc.send_signal(signal.SIGHUP)
            await _poll(lambda i=i: _reloaded(log, i + 1))  # type: ignore[misc]
        await _poll(lambda: _at_least(sim, peer_cycles))
        proc.send_signal(signal.SIGTERM)
        await asyncio.wait_for(proc.wait(), 30.0)
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
        await sim.stop()
    stop: dict[str, float] = next(json.loads(ln) for ln in log.read_text().splitlines()
                                  if '"daemon_stopped"' in ln)
    return stop


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reloads", type=int, default=50)
    ap.add_argument("--time-scale", type=float, default=50.0,
                    help="machine s per real s (50: a 20 ms real period)")
    args = ap.parse_args()
    got = asyncio.run(_daemon(args.time_scale, args.reloads, 0))
    peer = asyncio.run(_daemon(args.time_scale, 0, int(got["cycles"])))
    period_ms = 1000.0 / args.time_scale
    print(f"reloads {got['reloads']} (model changed each time), real period {period_ms:g} ms")
    print(f"  with reloads: {got['cycles']} cycles, {got['overruns']} overruns (cycles missed)")
    print(f"  peer, no reload: {peer['cycles']} cycles, {peer['overruns']} overruns")


if __name__ == "__main__":
    main()
