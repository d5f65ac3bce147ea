"""A real LinuxCNC, headless, as the simulated machine's controller.

Not a stand-in: LinuxCNC itself (Debian's ``linuxcnc-uspace``) runs a small
mill (XYZ, mm, trivkins, simulated joints, external offsets on X, Y and Z at
``OFFSET_AV_RATIO`` 0.2; X's: `x_offset`, Y's: `y_offset`) from a configuration
written to a work folder, with the ``dummy`` display (it waits on its stdin:
closing it shuts LinuxCNC down). The plant's side is a second HAL component, ``<prefix>-plant``
(`drivers.linuxcnc.LinuxCncDriver` with output pins), driving the sensor
signals ``<prefix>-<channel>`` that compd's own pins join; the spindle speed is
LinuxCNC's (``spindle-speed-cmd`` <- ``spindle.0.speed-out``, set by the
G-code program that runs); the offset the plant sees is what motion applies
(``axis.z.eoffset``, µm).

The configuration is `drivers.sim.linuxcnc_config`. The HAL file a user adds for compd
is `hal_lines` with the prefix ``compd``
(`HAL_LINES`), less the plant's signals: `docs/protocols.md`. A controller here
names its signals and components with a prefix of its own (`LinuxCncSimController.
prefix`, ``compd-t<pid>``): a compd left running by a test finds none of them in
another LinuxCNC, and the names are the run's alone.

As root, ``rtapi_app`` runs with the fallback uid ``RTAPI_UID`` (nobody) and a
FIFO that uid can write (``RTAPI_FIFO_PATH`` in the run's work folder). One
LinuxCNC runs per machine: `start()` takes the machine's lock
(`drivers.sim.linuxcnc_host`: waits while another run holds it; refuses with
`ForeignLinuxCnc` when a LinuxCNC it did not start runs) held until `stop()`,
which runs ``halrun -U`` only for its own LinuxCNC when that did not end by
itself. `unavailable()` says why LinuxCNC cannot run here (None when it can).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import pwd
import shutil
import subprocess
import tempfile
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from drivers.addresses import LinuxCncEoffset, LinuxCncGet, LinuxCncPin
from drivers.linuxcnc import LinuxCncDriver
from drivers.sim import linuxcnc_host
from drivers.sim.linuxcnc_config import (
    COUNT_UM,
    HAL_LINES,
    PERMIT_DOUT,
    REZERO_DOUT,
    SENSORS,
    hal_lines,
    mcode_hal_lines,
    write_config,
)
from drivers.sim.linuxcnc_host import ForeignLinuxCnc, LinuxCncBusy

#: the Python LinuxCNC's modules were built for (Debian's)
SYSTEM_PYTHON = "/usr/bin/python3"
CTL = Path(__file__).with_name("linuxcnc_ctl.py")
#: seconds LinuxCNC may take to come up (a loaded 2-core machine is slow)
START_DEADLINE_S = 120.0
#: seconds LinuxCNC's processes may take to end after its start script did
END_DEADLINE_S = 30.0
#: seconds the plant waits for motion to apply a requested offset
SETTLE_DEADLINE_S = 10.0
#: the address fields that name a HAL signal
NETS = frozenset({"net", "counts_net", "enable_net"})


def unavailable() -> str | None:
    """Why a headless LinuxCNC cannot run here; None when it can."""
    if shutil.which("linuxcnc") is None or shutil.which("halrun") is None:
        return "LinuxCNC is not installed (apt-get install linuxcnc-uspace)"
    if not os.path.exists(SYSTEM_PYTHON):
        return f"no {SYSTEM_PYTHON} for LinuxCNC's Python modules"
    probe = subprocess.run([SYSTEM_PYTHON, "-I", "-c", "import hal, linuxcnc"],
                           capture_output=True, text=True, timeout=60, check=False)
    if probe.returncode != 0:
        return f"LinuxCNC's hal/linuxcnc modules do not import under {SYSTEM_PYTHON}"
    return None


def _cleanup(env: dict[str, str]) -> None:
    """LinuxCNC's own cleanup of realtime processes and shared memory: only ever for
    a LinuxCNC this run started (`env`: the one it was started with)."""
    with contextlib.suppress(OSError, subprocess.SubprocessError):
        subprocess.run(["halrun", "-U"], capture_output=True, timeout=60, check=False,
                       env=env)


def _gone(deadline_s: float) -> bool:
    """Wait until no LinuxCNC runs here (the caller's own ending: it holds the
    machine's lock); False when one still does after `deadline_s`."""
    end = time.monotonic() + deadline_s
    while linuxcnc_host.foreign() is not None:
        if time.monotonic() > end:
            return False
        time.sleep(0.05)
    return True


def _env(folder: Path) -> dict[str, str]:
    """LinuxCNC's environment; as root, rtapi_app's FIFO in the run's own `folder`
    (the same for start and cleanup, or ``halrun -U`` cannot reach the instance)."""
    env = dict(os.environ, RUNTESTS="1")
    if os.geteuid() == 0:  # rtapi_app refuses root without a fallback uid
        fifo = folder / "rtapi"
        fifo.mkdir(exist_ok=True)
        fifo.chmod(0o777)
        env["RTAPI_UID"] = str(pwd.getpwnam("nobody").pw_uid)
        env["RTAPI_FIFO_PATH"] = str(fifo / "rtapi_fifo")
    return env


class LinuxCncSimController:
    """Headless LinuxCNC with the plant's HAL component (see the module)."""

    protocol = "linuxcnc"
    endpoint = "linuxcnc://localhost"

    def __init__(self, host: str = "127.0.0.1", port: int = 0, *,
                 folder: Path | None = None) -> None:
        #: the run's own prefix of signal and component names (module docstring)
        self.prefix = f"compd-t{os.getpid()}"
        #: the HAL component name a compd against this machine takes
        self.component = self.prefix
        p = self.prefix
        self.channels: dict[str, Any] = {
            name: LinuxCncPin(pin=name.replace("_", "-"), net=f"{p}-{name}")
            for name in SENSORS}
        self.channels["spindle_rpm"] = LinuxCncPin(pin="spindle-rpm", net="spindle-speed-cmd")
        self.outputs_map: dict[str, Any] = {
            "offset": LinuxCncEoffset(kind="eoffset", axis="z", scale=COUNT_UM,
                                      eoffset_scale=COUNT_UM / 1000.0,
                                      counts_net=f"{p}-eoffset-counts",
                                      enable_net=f"{p}-eoffset-enable"),
            "heartbeat": LinuxCncPin(pin="heartbeat", net=f"{p}-heartbeat", type="s32"),
            "status": LinuxCncPin(pin="status", net=f"{p}-status", type="s32")}
        #: X's external offset, on signals of its own (`x_eoffset_hal_lines`), and X's
        #: position as LinuxCNC reports it (mm): an [output.axes.x] at its position
        self.x_offset = LinuxCncEoffset(kind="eoffset", axis="x", scale=COUNT_UM,
                                        eoffset_scale=COUNT_UM / 1000.0,
                                        counts_net=f"{p}-x-eoffset-counts",
                                        enable_net=f"{p}-x-eoffset-enable")
        self.x_position = LinuxCncGet(kind="get", hal="axis.x.pos-cmd")
        #: Y's external offset, on signals of its own, as X's
        self.y_offset = LinuxCncEoffset(kind="eoffset", axis="y", scale=COUNT_UM,
                                        eoffset_scale=COUNT_UM / 1000.0,
                                        counts_net=f"{p}-y-eoffset-counts",
                                        enable_net=f"{p}-y-eoffset-enable")
        self.y_position = LinuxCncGet(kind="get", hal="axis.y.pos-cmd")
        #: the controller's state for [output] machine_on / estop / homed
        self.states: dict[str, Any] = {
            "machine_on": LinuxCncGet(kind="get", hal="motion.motion-enabled"),
            "estop": LinuxCncGet(kind="get", hal="iocontrol.0.user-enable-out", invert=True),
            "homed": LinuxCncGet(kind="get", hal="motion.is-all-homed")}
        #: [output] update_permitted and rezero as G-code sets them (`mcode_hal_lines`)
        self.mcode_inputs: dict[str, Any] = {
            "update_permitted": LinuxCncPin(pin="update-permitted", net=f"{p}-permit",
                                            type="bit"),
            "rezero": LinuxCncPin(pin="rezero", net=f"{p}-rezero", type="bit")}
        self.probes: dict[str, Any] = {}
        self._given = folder
        self.folder: Path | None = None
        self._tmp: tempfile.TemporaryDirectory[str] | None = None
        #: whether this controller holds the machine's LinuxCNC lock
        self._locked = False
        self._env: dict[str, str] = {}
        self._proc: subprocess.Popen[bytes] | None = None
        self._plant: LinuxCncDriver | None = None

    # -- lifecycle -----------------------------------------------------------------

    async def start(self) -> None:
        why = unavailable()
        if why is not None:
            raise RuntimeError(why)
        try:
            await asyncio.to_thread(self._start_sync)
            self._plant = LinuxCncDriver(
                self.endpoint, {
                    "offset_um": LinuxCncGet(kind="get", hal="axis.z.eoffset", scale=1000.0),
                    "request_um": LinuxCncGet(kind="get", hal="axis.z.eoffset-request",
                                              scale=1000.0),
                    "x_offset_um": LinuxCncGet(kind="get", hal="axis.x.eoffset", scale=1000.0),
                    "x_request_um": LinuxCncGet(kind="get", hal="axis.x.eoffset-request",
                                                scale=1000.0),
                    "x_pos_mm": LinuxCncGet(kind="get", hal="axis.x.pos-cmd"),
                    "y_pos_mm": LinuxCncGet(kind="get", hal="axis.y.pos-cmd"),
                    "y_offset_um": LinuxCncGet(kind="get", hal="axis.y.eoffset", scale=1000.0),
                    "y_request_um": LinuxCncGet(kind="get", hal="axis.y.eoffset-request",
                                                scale=1000.0),
                    # changes at every servo period (its length in CPU cycles): a
                    # change seen means motion has run since, and taken compd's last write
                    "servo_mark": LinuxCncGet(kind="get", hal="motion.servo.last-period"),
                    "spindle_rpm": LinuxCncGet(kind="get", hal="spindle.0.speed-out"),
                    "heartbeat": LinuxCncPin(pin="heartbeat", net=f"{self.prefix}-heartbeat",
                                             type="s32"),
                    "status": LinuxCncPin(pin="status", net=f"{self.prefix}-status",
                                          type="s32")},
                {n: LinuxCncPin(pin=n.replace("_", "-"), net=f"{self.prefix}-{n}")
                 for n in SENSORS},
                timeout_s=10.0, connect_timeout_s=60.0, component=f"{self.prefix}-plant",
                python=SYSTEM_PYTHON)
            await self._plant.connect()
            await self.control("on")
        except BaseException:
            await self.stop()
            raise

    def _start_sync(self) -> None:
        # one LinuxCNC per machine: waits while another run holds it; refuses to
        # start beside (or clean up) a LinuxCNC somebody else started
        linuxcnc_host.acquire()
        self._locked = True
        if self._given is not None:
            self.folder = self._given
        else:
            self._tmp = tempfile.TemporaryDirectory(prefix="compd-linuxcnc-")
            self.folder = Path(self._tmp.name)
        self.folder.chmod(0o755)
        ini = write_config(self.folder, self.prefix)
        self._env = _env(self.folder)
        log = (self.folder / "linuxcnc.log").open("wb")
        self._proc = subprocess.Popen(["linuxcnc", str(ini)], cwd=self.folder,
                                      stdin=subprocess.PIPE, stdout=log,
                                      stderr=subprocess.STDOUT, env=self._env,
                                      start_new_session=True)
        log.close()
        deadline = time.monotonic() + START_DEADLINE_S
        while b"DUMMY DISPLAY" not in (self.folder / "linuxcnc.log").read_bytes():
            if self._proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError("LinuxCNC did not start: " + self.log_tail())
            time.sleep(0.05)

    def log_tail(self, chars: int = 2000) -> str:
        if self.folder is None:
            return ""
        path = self.folder / "linuxcnc.log"
        return path.read_text(errors="replace")[-chars:] if path.exists() else ""

    async def stop(self) -> None:
        if self._plant is not None:
            await self._plant.close()
            self._plant = None
        await asyncio.to_thread(self._stop_sync)

    def _stop_sync(self) -> None:
        if not self._locked:  # it never got the machine's LinuxCNC: nothing here is ours
            return
        proc, self._proc = self._proc, None
        if proc is not None:
            ended = True
            with contextlib.suppress(OSError):
                if proc.stdin is not None:
                    proc.stdin.close()  # the dummy display's "press ENTER": shut down
            try:
                proc.wait(60)
            except subprocess.TimeoutExpired:
                ended = False
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, 9)
                proc.wait(10)
            # its processes (linuxcncsvr, rtapi_app) end after its start script: the
            # lock is given back once they are gone, or the next run would see them
            # as a LinuxCNC it did not start
            if not ended or not _gone(END_DEADLINE_S):
                _cleanup(self._env)  # ours, and it did not clean up after itself
                _gone(END_DEADLINE_S)
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None
        self._locked = False
        linuxcnc_host.release()

    # -- the machine's side --------------------------------------------------------

    def own_config(self, doc: dict[str, Any]) -> dict[str, Any]:
        """A compd config document written for the HAL file of docs/protocols.md
        (signals ``compd-...``, component ``compd``) made to join this machine's
        signals instead: the names of this run (`prefix`)."""
        def rename(value: Any) -> Any:
            if isinstance(value, dict):
                if value.get("kind") == "eoffset":  # its signals' names by default
                    value = {"counts_net": "compd-eoffset-counts",
                             "enable_net": "compd-eoffset-enable", **value}
                return {k: (f"{self.prefix}{v[len('compd'):]}" if k in NETS and isinstance(
                    v, str) and v.startswith("compd-") else rename(v)) for k, v in value.items()}
            return value

        out: dict[str, Any] = rename(doc)
        out.setdefault("controller", {}).setdefault("linuxcnc", {})["component"] = self.component
        return out

    async def control(self, *command: str) -> dict[str, Any]:
        """A `drivers.sim.linuxcnc_ctl` command (``on``, ``off``, ``estop``,
        ``run FILE``, ``stat``); returns ``linuxcnc.stat()`` after it."""
        proc = await asyncio.create_subprocess_exec(
            SYSTEM_PYTHON, "-I", str(CTL), *command, stdout=asyncio.subprocess.PIPE)
        out, _ = await proc.communicate()
        answer: dict[str, Any] = json.loads(out or b'{"e": "no answer"}')
        if proc.returncode != 0 or "e" in answer:
            raise RuntimeError(f"linuxcnc {' '.join(command)}: {answer.get('e')}")
        return answer

    async def hal(self) -> dict[str, float]:
        """What LinuxCNC's HAL shows of compd: the Z offset applied (µm), the
        heartbeat and the status word."""
        assert self._plant is not None
        got = await self._plant.read(["offset_um", "heartbeat", "status"])
        return {n: s.value for n, s in got.items()}

    async def spindle_rpm(self) -> float:
        """The spindle speed LinuxCNC commands now (``spindle.0.speed-out``, rpm;
        0 while the spindle is off), as the program running sets it."""
        assert self._plant is not None
        return (await self._plant.read(["spindle_rpm"]))["spindle_rpm"].value

    async def publish(self, values: Mapping[str, float]) -> None:
        assert self._plant is not None
        await self._plant.write({n: v for n, v in values.items() if n in SENSORS})

    async def settled(self, deadline_s: float = SETTLE_DEADLINE_S) -> dict[str, float]:
        """`hal()` once motion has applied the offset compd requested (the
        external offset planner moves at OFFSET_AV_RATIO of the axis' limits:
        milliseconds for a few µm); a condition, bounded by `deadline_s`."""
        return await self._applied(("",), ("heartbeat", "status"), deadline_s)

    async def settled_axes(self, deadline_s: float = SETTLE_DEADLINE_S) -> dict[str, float]:
        """Once motion has applied every external offset compd requested: X's, Y's
        and Z's offsets applied (µm, ``x_offset_um``, ``y_offset_um``,
        ``offset_um``) and X's and Y's positions (mm, ``x_pos_mm``, ``y_pos_mm``); a
        condition, bounded by `deadline_s`."""
        return await self._applied(("", "x_", "y_"), ("x_pos_mm", "y_pos_mm"), deadline_s)

    async def _applied(self, axes: tuple[str, ...], also: tuple[str, ...],
                       deadline_s: float) -> dict[str, float]:
        """Each of `axes`' offsets (µm, ``<axis>offset_um``) and the values `also`
        names, once motion has applied every offset compd requested on them: a servo
        period has run since this was asked (``motion.servo.last-period`` changed;
        before, motion may not yet have latched compd's last write, and its earlier
        request and offset, equal to each other, read as settled on a busy machine)
        and each offset has reached its request. Bounded by `deadline_s`."""
        assert self._plant is not None
        end = time.monotonic() + deadline_s
        offsets = [f"{a}offset_um" for a in axes]
        names = [*offsets, *(f"{a}request_um" for a in axes), *also, "servo_mark"]
        mark = (await self._plant.read(["servo_mark"]))["servo_mark"].value
        while True:
            v = {n: s.value for n, s in (await self._plant.read(names)).items()}
            if (v["servo_mark"] != mark and all(abs(v[f"{a}offset_um"] - v[f"{a}request_um"])
                                                < 1e-3 for a in axes)) \
                    or time.monotonic() > end:
                return {n: v[n] for n in (*offsets, *also)}
            await asyncio.sleep(0.001)

    async def outputs(self) -> dict[str, float]:
        got = await self.settled()
        return {"offset": got["offset_um"], "heartbeat": got["heartbeat"],
                "status": got["status"]}

    async def forget_outputs(self) -> None:
        """Machine off and on again: LinuxCNC zeroes the external offset."""
        await self.control("off")
        await self.control("on")


__all__ = ["COUNT_UM", "HAL_LINES", "PERMIT_DOUT", "REZERO_DOUT", "SENSORS", "ForeignLinuxCnc",
           "LinuxCncBusy", "LinuxCncSimController", "hal_lines", "mcode_hal_lines",
           "unavailable", "write_config"]
