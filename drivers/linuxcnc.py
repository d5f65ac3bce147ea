"""LinuxCNC driver: compd as a HAL user-space component.

The HAL work happens in a child process (`drivers.linuxcnc_hal`, run under
the system Python that LinuxCNC's ``hal`` module was built for: option
``python``), which this driver talks to over a pipe, one JSON line per
request. Why not ``import hal`` here: see that module (SIGTERM, a clean
component on kill -9, compd's interpreter need not be Debian's).

The session of the shared lifecycle (`drivers.link.Link`) is that process:
opening it creates the component and joins every pin to its HAL signal; a
process that ended (LinuxCNC shut down: ``halcmd unload all``) or a request
not answered within ``timeout_s`` drops it, and the next call after the
backoff delay starts a new one. The endpoint is ``linuxcnc://localhost``:
HAL is shared memory on this machine.

Every value is GOOD, stamped with the time its answer arrived. An external
offset (address kind ``eoffset``, one output per axis: X, Y and Z at once) is
written in counts against what LinuxCNC holds and refused while LinuxCNC
takes no offset (machine off, E-stop, not homed): `drivers.linuxcnc_hal`.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from drivers.addresses import LinuxCncEoffset, LinuxCncGet, LinuxCncPin
from drivers.backoff import Backoff
from drivers.base import Quality, Sample
from drivers.endpoint import endpoint_of
from drivers.errors import BadAddress, ConnectionLost, ControllerTimeout, DriverError, WriteRejected
from drivers.link import Link, LinkedDriver
from drivers.linuxcnc_options import MAX_LEFT_BEHIND, linuxcnc_name_clash, long_hal_name

LinuxCncAddress = LinuxCncPin | LinuxCncEoffset | LinuxCncGet

#: the HAL side, run as a script (never imported by compd)
HAL_SIDE = Path(__file__).with_name("linuxcnc_hal.py")
#: a HAL line is short; a longer one is a broken HAL side
MAX_LINE = 1 << 20
#: how long an ending HAL side gets after end-of-file, and after SIGTERM
END_WAIT_S = 2.0
#: the most of a HAL side's last error line kept (its stderr: a Python traceback's
#: last line, HAL's own message)
ERROR_CHARS = 500


def _check(role: str, table: Mapping[str, object]) -> dict[str, LinuxCncAddress]:
    out: dict[str, LinuxCncAddress] = {}
    for name, addr in table.items():
        if not isinstance(addr, LinuxCncPin | LinuxCncEoffset | LinuxCncGet):
            raise BadAddress(f"{role} address is not a LinuxCNC address: {addr!r}",
                             channel=name)
        if role == "output" and isinstance(addr, LinuxCncGet):
            raise BadAddress("a 'get' address is read only: an output needs a pin (or "
                             "the eoffset)", channel=name, address=addr.describe())
        out[name] = addr
    return out


def _one_eoffset_per_axis(channels: Mapping[str, LinuxCncAddress],
                          outputs: Mapping[str, LinuxCncAddress]) -> None:
    """An external offset is an output, one per axis: two writers of one axis's
    offset would each count against the other's changes."""
    for name, a in channels.items():
        if isinstance(a, LinuxCncEoffset):
            raise BadAddress("an eoffset address is an output only, not a channel",
                             channel=name, address=a.describe())
    taken: dict[str, str] = {}
    for name, a in outputs.items():
        if not isinstance(a, LinuxCncEoffset):
            continue
        first = taken.setdefault(a.axis, name)
        if first != name:
            raise BadAddress(f"one eoffset address per axis: {name!r} and {first!r} both "
                             f"write axis {a.axis.upper()}'s external offset",
                             channel=name, address=a.describe())


class _Session:
    """The HAL side's process, its pipe, and the last line it wrote on stderr."""

    def __init__(self, proc: asyncio.subprocess.Process) -> None:
        self.proc = proc
        assert proc.stdin is not None and proc.stdout is not None
        self.stdin = proc.stdin
        self.stdout = proc.stdout
        #: the last non-empty line of its stderr ("" while none), at most ERROR_CHARS
        self.last_error = ""
        self._stderr = (asyncio.ensure_future(self._drain(proc.stderr))
                        if proc.stderr is not None else None)

    async def _drain(self, stream: asyncio.StreamReader) -> None:
        """Read its stderr to the end (a full pipe would stop it), keeping the last line."""
        with contextlib.suppress(OSError, ValueError):
            while line := await stream.readline():
                text = line.decode(errors="replace").strip()
                if text:
                    self.last_error = text[-ERROR_CHARS:]

    async def ended(self) -> str:
        """Its exit status and last error line, once it has ended (for a start that
        got no greeting)."""
        status = await self.proc.wait()
        if self._stderr is not None:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(asyncio.shield(self._stderr), END_WAIT_S)
        why = f": {self.last_error}" if self.last_error else ""
        return f"the HAL side ended at start (status {status}){why}"

    async def ask(self, request: dict[str, Any], timeout_s: float) -> dict[str, Any]:
        self.stdin.write(json.dumps(request, separators=(",", ":")).encode() + b"\n")
        async with asyncio.timeout(timeout_s):
            await self.stdin.drain()
            line = await self.stdout.readline()
        if not line:
            raise ConnectionLost("the HAL side ended (LinuxCNC shut down?)")
        answer: dict[str, Any] = json.loads(line)
        return answer

    async def end(self) -> None:
        """End-of-file on its stdin, then SIGTERM, and SIGKILL only for a process that
        ignores both (it leaves its component behind, which the next HAL side steps
        around: `drivers.linuxcnc_hal`)."""
        with contextlib.suppress(ProcessLookupError, OSError, RuntimeError):
            self.stdin.close()
        for stop in (None, self.proc.terminate, self.proc.kill):
            if stop is not None:
                with contextlib.suppress(ProcessLookupError):
                    stop()
            try:
                await asyncio.wait_for(self.proc.wait(), END_WAIT_S)
                break
            except TimeoutError:
                continue
        if self._stderr is not None and self.proc.returncode is not None:
            with contextlib.suppress(TimeoutError, asyncio.CancelledError):
                await asyncio.wait_for(self._stderr, END_WAIT_S)


def _error(answer: dict[str, Any], what: str) -> DriverError:
    """A failure answer of the HAL side as our error."""
    message, kind, name = str(answer.get("e")), answer.get("k"), answer.get("n")
    if kind == "bad_address":
        return BadAddress(message, channel=name)
    if kind == "rejected":
        return WriteRejected(message, channel=name, permanent=False)
    if kind == "timeout":
        return ControllerTimeout(f"{what}: {message}", channel=name)
    return ConnectionLost(f"{what}: {message}", channel=name)


class LinuxCncDriver(LinkedDriver):
    """Async access to LinuxCNC's HAL (see the module docstring)."""

    protocol = "linuxcnc"

    def __init__(self, endpoint: str, channels: Mapping[str, object],
                 outputs: Mapping[str, object], *, timeout_s: float = 0.5,
                 connect_timeout_s: float = 10.0, backoff: Backoff | None = None,
                 component: str = "compd", python: str = "/usr/bin/python3") -> None:
        if not timeout_s > 0:
            raise ValueError("timeout_s must be positive")
        endpoint_of("linuxcnc", endpoint)  # this machine only (ProtocolSpec.local_only)
        why = linuxcnc_name_clash(component)
        if why is not None:
            raise ValueError(f"component: {why}")
        self.endpoint = endpoint
        self.channels = _check("channel", channels)
        self.outputs = _check("output", outputs)
        _one_eoffset_per_axis(self.channels, self.outputs)
        long = long_hal_name(component, {**self.channels, **self.outputs})
        if long is not None:
            raise BadAddress(long[1], channel=long[0])
        self.timeout_s = timeout_s
        self.connect_timeout_s = connect_timeout_s
        self.component = component
        self.python = python
        #: axis.L.eoffset-scale of each eoffset output (by its name) as LinuxCNC
        #: reported it at the last connect
        self.eoffset_scales: dict[str, float] = {}
        self._lock = asyncio.Lock()
        #: a lost HAL side still ending (`_drop`)
        self._ending: asyncio.Future[None] | None = None
        self._link: Link[_Session] = Link(
            f"HAL component {component!r}", backoff or Backoff(), timeout_s,
            open=self._start, drop=self._drop, connect_errors=(OSError, ValueError),
            lost_errors=(OSError, ValueError), alive=lambda s: s.proc.returncode is None,
            # the start's own bound, after the last HAL side's end (`_start`)
            connect_timeout_s=connect_timeout_s + 3 * END_WAIT_S)

    def _spec(self) -> dict[str, Any]:
        pins: list[dict[str, Any]] = []
        gets: list[dict[str, Any]] = []
        eoffsets: list[dict[str, Any]] = []
        for role, table in (("in", self.channels), ("out", self.outputs)):
            for name, a in table.items():
                if isinstance(a, LinuxCncGet):
                    gets.append({"name": name, "hal": a.hal, "scale": a.scale,
                                 "invert": a.invert})
                elif isinstance(a, LinuxCncPin):
                    pins.append({"name": name, "pin": a.pin, "net": a.net, "type": a.type,
                                 "dir": role, "invert": a.invert})
                else:
                    counts_pin, enable_pin = a.pins
                    eoffsets.append({"name": name, "axis": a.axis, "counts_pin": counts_pin,
                                     "counts_net": a.counts_net, "enable_pin": enable_pin,
                                     "enable_net": a.enable_net, "scale": a.scale,
                                     "eoffset_scale": a.eoffset_scale})
        return {"component": self.component, "pins": pins, "eoffsets": eoffsets,
                "gets": gets, "wait_s": 0.5 * self.timeout_s, "max_left": MAX_LEFT_BEHIND}

    async def _start(self) -> _Session:
        """The HAL side (the link runs this in a task of its own: starting a Python
        takes longer than a fast cycle's read may wait, and a read that gives up
        leaves the start going on for the next call to take)."""
        ending, self._ending = self._ending, None
        if ending is not None:  # the last HAL side must be gone: it holds the name
            await ending
        proc = await asyncio.create_subprocess_exec(
            self.python, "-I", str(HAL_SIDE), json.dumps(self._spec()),
            stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.PIPE, limit=MAX_LINE)
        session = _Session(proc)
        try:
            async with asyncio.timeout(self.connect_timeout_s):
                line = await session.stdout.readline()
            hello: dict[str, Any] = json.loads(line) if line else {
                "e": await session.ended(), "k": "lost"}
        except BaseException:
            await session.end()
            raise
        if "ready" not in hello:
            await session.end()
            raise _error(hello, f"connect to LinuxCNC HAL as {self.component!r}")
        self.eoffset_scales = {str(n): float(v)
                               for n, v in (hello.get("eoffset_scales") or {}).items()}
        return session

    async def _drop(self, session: _Session, closing: bool) -> None:
        """A lost session ends in the background (a call never waits on a HAL side
        that hangs); the next open waits for it. Closing waits here."""
        ending = asyncio.ensure_future(session.end())
        if closing:
            await ending
        else:
            self._ending = ending

    async def close(self) -> None:
        await self._link.close()  # a start in progress is cancelled: it ends its process
        ending, self._ending = self._ending, None
        if ending is not None:
            await ending

    async def _ask(self, request: dict[str, Any], what: str) -> dict[str, Any]:
        async def op(s: _Session) -> dict[str, Any]:
            answer = await s.ask(request, self.timeout_s)
            if "e" in answer:
                raise _error(answer, what)
            return answer

        async with self._lock:
            return await self._link.call(op, what)

    async def read(self, names: Sequence[str]) -> dict[str, Sample]:
        for name in names:
            if name not in self.channels and name not in self.outputs:
                raise BadAddress("unknown channel or output name", channel=name)
        answer = await self._ask({"r": list(names)}, "read")
        now = time.time()
        values: dict[str, float] = answer["v"]
        return {name: Sample(float(values[name]), now, Quality.GOOD) for name in names}

    async def write(self, values: Mapping[str, float]) -> None:
        for name in values:
            if name not in self.outputs:
                raise BadAddress("unknown output name (not writable)", channel=name)
        await self._ask({"w": {n: float(v) for n, v in values.items()}}, "write")


__all__ = ["HAL_SIDE", "LinuxCncDriver"]
