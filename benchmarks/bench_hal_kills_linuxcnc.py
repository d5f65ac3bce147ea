"""LinuxCNC's HAL signal table before and after 20 SIGKILLs of compd's HAL side.

A headless LinuxCNC (`drivers.sim.linuxcnc_machine`); compd's HAL side joins the
machine's signals (the sensors, the spindle command ``spindle-speed-cmd`` that
motion's ``spindle.0.speed-out`` drives, the offset's counts, the heartbeat and
the status word) and is killed with SIGKILL 20 times, each restart stepping
around the components the dead ones left. First, names that collide with
LinuxCNC's own pins (``spindle``, ``motion``, ``axis``, ``J0_pid``) are tried:
the driver refuses them, and a HAL side given one anyway refuses to start. The
peer, in the same run: the name-prefix rule compd used before, evaluated on the
same table (which writers it would have unlinked for a dead component of that
name). Then ``S3000 M3`` by MDI: the spindle command must reach the signal.

Prints ``halcmd show sig`` before and after (compd's own signals are written by
the last HAL side after), then one JSON line; exits 1 when any of LinuxCNC's
writers changed or the spindle command did not arrive, 69 where LinuxCNC cannot
run or a LinuxCNC it did not start runs.

Run: .venv/bin/python benchmarks/bench_hal_kills_linuxcnc.py [--kills N]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from compd.argtypes import count  # noqa: E402
from compd.sysexits import EX_UNAVAILABLE  # noqa: E402
from drivers.errors import BadAddress, ConnectionLost  # noqa: E402
from drivers.linuxcnc import LinuxCncDriver  # noqa: E402
from drivers.sim.linuxcnc_machine import (  # noqa: E402
    ForeignLinuxCnc,
    LinuxCncBusy,
    LinuxCncSimController,
    unavailable,
)

COLLIDING = ("spindle", "motion", "axis", "J0_pid")


def show_sig() -> str:
    return subprocess.run(["halcmd", "show", "sig"], capture_output=True, text=True,
                          timeout=30, check=True).stdout


def components() -> list[str]:
    """The names in ``halcmd show comp``."""
    out = subprocess.run(["halcmd", "-s", "show", "comp"], capture_output=True, text=True,
                         timeout=30, check=True).stdout
    return [f[2] for line in out.splitlines() if len(f := line.split()) >= 3]


def getp(name: str) -> float:
    return float(subprocess.run(["halcmd", "-s", "getp", name], capture_output=True,
                                text=True, timeout=30, check=True).stdout)


def table(text: str) -> dict[str, tuple[str | None, tuple[str, ...]]]:
    """``halcmd show sig`` as signal -> (writer, readers), values left out."""
    out: dict[str, tuple[str | None, tuple[str, ...]]] = {}
    name: str | None = None
    writer: str | None = None
    readers: list[str] = []
    for line in text.splitlines():
        f = line.split()
        if len(f) == 3 and not line.startswith(" "):  # type value name
            if name is not None:
                out[name] = (writer, tuple(sorted(readers)))
            name, writer, readers = f[2], None, []
        elif len(f) == 2 and f[0] in ("<==", "==>", "<=>"):
            if f[0] == "<==":
                writer = f[1]
            else:
                readers.append(f[1])
    if name is not None:
        out[name] = (writer, tuple(sorted(readers)))
    return out


def old_rule_unlinks(before: dict[str, tuple[str | None, tuple[str, ...]]],
                     component: str, nets: list[str]) -> list[str]:
    """The writers the name-prefix rule compd used before would have unlinked, for
    a dead component `component` joined to `nets` (inputs too)."""
    return [w for net in nets if (w := before.get(net, (None, ()))[0]) is not None
            and w.startswith(component + ".")]


async def run(kills: int) -> dict[str, Any]:
    lcnc = LinuxCncSimController()
    await lcnc.start()
    try:
        channels = {**lcnc.channels}
        outputs = lcnc.outputs_map
        before_text = show_sig()
        before = table(before_text)
        nets = [a.net for a in channels.values()] + [
            outputs["offset"].counts_net, outputs["offset"].enable_net,
            outputs["heartbeat"].net, outputs["status"].net]
        refused: dict[str, str] = {}
        peer: dict[str, list[str]] = {}
        for name in COLLIDING:
            peer[name] = old_rule_unlinks(before, name, nets)
            try:
                LinuxCncDriver(lcnc.endpoint, channels, outputs, component=name)
                refused[name] = "driver: accepted"
            except ValueError:
                refused[name] = "driver: refused"
            probe = LinuxCncDriver(lcnc.endpoint, channels, outputs, timeout_s=10.0,
                                   connect_timeout_s=60.0, component=lcnc.component)
            probe.component = name  # past the driver's check: what the HAL side does
            try:
                await probe.connect()
                refused[name] += "; HAL side: started"
            except BadAddress as exc:
                refused[name] += f"; HAL side: refused ({exc})"
            finally:
                await probe.close()
        driver = LinuxCncDriver(lcnc.endpoint, channels, outputs, timeout_s=10.0,
                                connect_timeout_s=60.0, component=lcnc.component)
        held: list[float] = []
        try:
            for k in range(kills):
                await driver.connect()
                await driver.write({"heartbeat": k + 1, "status": 1})
                session = driver._link.session
                assert session is not None
                session.proc.kill()
                await session.proc.wait()
                with contextlib.suppress(ConnectionLost):  # the link sees it gone
                    await driver.read(["bearing"])
            await driver.connect()  # the HAL side after the last kill, left running
            held.append((await driver.read(["offset"]))["offset"].value)
            await lcnc.control("mdi", "S3000 M3")
            spindle = (await driver.read(["spindle_rpm"]))["spindle_rpm"].value
            after_text = show_sig()
            after = table(after_text)
        finally:
            await driver.close()
        ours = set(nets) - {"spindle-speed-cmd"}
        changed = {s: (before[s][0], after.get(s, (None, ()))[0]) for s in before
                   if s not in ours and before[s][0] != after.get(s, (None, ()))[0]}
        base = lcnc.component
        dead = [n for n in components() if n == base
                or (n.startswith(base + "-") and n[len(base) + 1:].isdigit())]
        print("# halcmd show sig, before\n" + before_text)
        print(f"# halcmd show sig, after {kills} kills\n" + after_text)
        return {"figure": "hal_kills_linuxcnc", "kills": kills, "colliding_names": refused,
                "peer_name_prefix_rule_would_unlink": peer,
                "linuxcnc_writers_changed": changed,
                "compd_writers_after": {s: after[s][0] for s in sorted(ours) if s in after},
                "spindle_speed_cmd_after_S3000_M3": spindle,
                "spindle_speed_out": getp("spindle.0.speed-out"),
                "components_left_by_kills": len(dead), "offset_held_um": held[0]}
    finally:
        await lcnc.stop()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kills", type=count(1, 20), default=20)
    args = parser.parse_args()
    why = unavailable()
    if why is not None:
        print(f"bench_hal_kills_linuxcnc: {why}", file=sys.stderr)
        return EX_UNAVAILABLE
    try:
        result = asyncio.run(run(args.kills))
    except (ForeignLinuxCnc, LinuxCncBusy) as exc:
        print(f"bench_hal_kills_linuxcnc: {exc}", file=sys.stderr)
        return EX_UNAVAILABLE
    print(json.dumps(result))
    ok = (not result["linuxcnc_writers_changed"]
          and result["spindle_speed_cmd_after_S3000_M3"] == 3000.0
          and all("HAL side: refused" in v for v in result["colliding_names"].values()))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
