"""The HAL side of the LinuxCNC driver: a user-space HAL component in its own process.

Run by `drivers.linuxcnc` as ``python3 -I drivers/linuxcnc_hal.py SPEC`` under
the system Python that LinuxCNC's ``hal`` module was built for (Debian's
``/usr/bin/python3``), never imported by compd: it uses only the standard
library and ``hal``, so compd's own interpreter (a venv, another Python
version) does not have to load LinuxCNC's extension module. Why a process:

- ``hal.component`` turns SIGTERM into KeyboardInterrupt (``halcmd unload
  all``, LinuxCNC's shutdown, ends user components that way): inside the
  daemon it would fight compd's own SIGTERM handling;
- when compd dies (kill -9), this process reads end-of-file on stdin and
  exits, so HAL removes the component cleanly and a restarted compd can
  create it again; the signals it wrote keep their last values (HAL keeps a
  signal's value when its writer goes): the offset is held.

SPEC (JSON, one argument): ``{"component": "compd", "pins": [{"name",
"pin", "net", "type", "dir", "invert"}], "eoffsets": [{"name", "axis",
"counts_pin", "counts_net", "enable_pin", "enable_net", "scale",
"eoffset_scale"}] (one per axis), "gets": [{"name", "hal", "scale", "invert"}],
"wait_s": s, "max_left": n}`` (``max_left``: how many components of killed HAL sides it steps
around, `Component._create`)
(``gets``: read-only, any HAL pin or signal by name, as ``halcmd getp``). Each pin is created as
``<component>.<pin>`` and joined to the signal ``net`` (which the machine's
HAL file makes with a ``net`` line; a missing one is refused by name).

Requests, one JSON line each on stdin, one JSON line answers on stdout:
``{"r": [names]}`` -> ``{"v": {name: value}}``; ``{"w": {name: value}}`` ->
``{"ok": 1}``. A failure answers ``{"e": message, "k": kind, "n": name}``
with kind ``bad_address`` | ``rejected`` | ``timeout`` | ``lost``.
The first line written is ``{"ready": 1, "eoffset_scales": {name: s}}`` or a failure.

An external offset (``eoffset``, one per axis) is incremental in LinuxCNC:
``axis.L.eoffset-counts`` is read like a hand wheel, each change times
``axis.L.eoffset-scale`` is added to the offset while the machine is on,
homed and ``eoffset-enable`` is true, and LinuxCNC zeroes the offset at
machine on. So the value written (counts of the offset wanted) is turned
into a change of the counts pin against what LinuxCNC holds
(``axis.L.eoffset-request``), and the write waits until the servo thread
took it; a servo thread later than ``wait_s`` is a transient refusal, and the
next write counts from what LinuxCNC will hold once it takes the change. While
LinuxCNC does not take changes (machine off, E-stop, not homed) the counts are
left alone and the write is refused (``rejected``): no change is queued that
would jump the offset at machine on. The offsets of one write (X and Z) are
changed together and waited for together: the servo thread takes them in
the same period. The offset
read back is ``axis.L.eoffset`` (what motion applies) in counts, or the offset
requested while motion clips it at a soft limit (`Component._offset`).
"""

from __future__ import annotations

import contextlib
import importlib
import json
import os
import re
import signal
import subprocess
import sys
import time
from typing import Any, NamedTuple


def _answer(obj: dict[str, Any]) -> None:
    sys.stdout.write(json.dumps(obj, separators=(",", ":")) + "\n")
    sys.stdout.flush()


class Refused(Exception):
    def __init__(self, message: str, kind: str, name: str | None = None) -> None:
        super().__init__(message)
        self.kind = kind
        self.name = name


def _types(hal: Any) -> dict[str, Any]:
    return {"float": hal.HAL_FLOAT, "s32": hal.HAL_S32, "u32": hal.HAL_U32, "bit": hal.HAL_BIT}


class Component:
    """The HAL component, its pins and the external offset (see the module)."""

    def __init__(self, hal: Any, spec: dict[str, Any]) -> None:
        self.hal = hal
        #: components of killed HAL sides of ours: HAL's component id -> name
        self._dead: dict[int, str] = {}
        self.comp = self._create(spec["component"], int(spec.get("max_left", 20)))
        types = _types(hal)
        self.pins: dict[str, dict[str, Any]] = {}
        for p in spec["pins"]:
            direction = hal.HAL_IN if p["dir"] == "in" else hal.HAL_OUT
            self.comp.newpin(p["pin"], types[p["type"]], direction)
            self.pins[p["name"]] = p
        #: read-only: any HAL pin, signal or parameter by its name (name -> (hal name, scale))
        self.gets: dict[str, tuple[str, float, bool]] = {
            g["name"]: (g["hal"], float(g.get("scale", 1.0)), bool(g.get("invert")))
            for g in spec.get("gets", [])}
        #: the external offsets by name, one per axis
        self.eos: dict[str, dict[str, Any]] = {e["name"]: e for e in spec.get("eoffsets", [])}
        self.wait_s = float(spec.get("wait_s", 0.25))
        for eo in self.eos.values():
            self.comp.newpin(eo["counts_pin"], hal.HAL_S32, hal.HAL_OUT)
            self.comp.newpin(eo["enable_pin"], hal.HAL_BIT, hal.HAL_OUT)
        self.comp.ready()
        for p in spec["pins"]:
            self._join(p["pin"], p["net"], p["name"], drives=p["dir"] == "out")
        #: per offset name: axis.L.eoffset-scale as LinuxCNC holds it
        self.eoffset_scales: dict[str, float] = {}
        #: per offset name: the counts LinuxCNC will hold once its servo thread takes
        #: our last change (a write that returned before it did); absent when it
        #: holds what we wrote
        self.expect: dict[str, int] = {}
        for eo in self.eos.values():
            axis = f"axis.{eo['axis']}"
            scale = float(hal.get_value(f"{axis}.eoffset-scale"))
            want = eo.get("eoffset_scale")
            if not scale:
                raise Refused(f"{axis}.eoffset-scale is 0: set it in the HAL file "
                              f"(setp {axis}.eoffset-scale ...)", "bad_address", eo["name"])
            if want is not None and abs(want - scale) > 1e-9 * abs(want):
                raise Refused(f"{axis}.eoffset-scale is {scale:g}, the "
                              f"config says {want:g}", "bad_address", eo["name"])
            self.eoffset_scales[eo["name"]] = scale
            # start from what the counts signal holds (a restart: the last counts written)
            counts = hal.get_value(eo["counts_net"]) if self._has_signal(eo["counts_net"]) else 0
            self.comp[eo["counts_pin"]] = int(counts)
            self.comp[eo["enable_pin"]] = True
            self._join(eo["counts_pin"], eo["counts_net"], eo["name"], drives=True)
            self._join(eo["enable_pin"], eo["enable_net"], eo["name"], drives=True)

    def _create(self, name: str, max_left: int) -> Any:
        """The component `name`; when processes killed with SIGKILL left components of
        that name behind (HAL removes a user component only when its own process
        exits it), ``name-2``, ``name-3``... up to ``max_left`` of them (the HAL file
        names only signals, so the pins' names do not matter to it). A name that
        another live process or LinuxCNC itself holds, or under which pins of other
        components stand (``spindle`` and ``spindle.0.speed-out``), is refused."""
        comps = _components()
        self._dead = {c.cid: c.name for c in comps.values()
                      if c.user and _family(c.name, name) and not _alive(c.pid)}
        for n in range(1, max_left + 2):
            candidate = name if n == 1 else f"{name}-{n}"
            other = comps.get(candidate)
            if other is not None and other.cid in self._dead:
                continue  # left behind by a killed HAL side of ours: step around it
            if other is not None:
                why = (f"it is taken by the live process {other.pid} (another compd?)"
                       if other.user else "it is one of LinuxCNC's realtime components")
                raise Refused(f"cannot create HAL component {candidate!r}: {why}", "lost")
            foreign = self._foreign_pins(candidate)
            if foreign is not None:
                raise Refused(f"cannot create HAL component {candidate!r}: the HAL pin "
                              f"{foreign} of another component has that name: choose "
                              f"another controller.linuxcnc.component", "bad_address")
            try:
                return self.hal.component(candidate)
            except Exception as exc:  # HAL not running, or the name taken meanwhile
                raise Refused(f"cannot create HAL component {candidate!r}: is LinuxCNC "
                              f"running? ({exc})", "lost") from exc
        left = ", ".join(sorted(self._dead.values()))
        raise Refused(f"cannot create HAL component {name!r}: {len(self._dead)} components "
                      f"of killed compd HAL sides are left in HAL ({left}); HAL frees them "
                      f"only when LinuxCNC restarts", "lost")

    def _foreign_pins(self, candidate: str) -> str | None:
        """A pin or parameter ``<candidate>.*`` owned by a component other than a dead
        one of ours, None when there is none."""
        for owner, pin in _pins(f"{candidate}."):
            if owner not in self._dead:
                return pin
        return None

    def _has_signal(self, net: str) -> bool:
        return any(s["NAME"] == net for s in self.hal.get_info_signals())

    def _join(self, pin: str, net: str, name: str, *, drives: bool) -> None:
        full = f"{self.comp.getprefix()}.{pin}"
        if not self._has_signal(net):
            raise Refused(f"HAL signal {net!r} does not exist: add a 'net {net} ...' line to "
                          f"the machine's HAL file for {full}", "bad_address", name)
        if drives:  # an input joins beside the signal's writer, whoever that is
            self._free_writer(net)
        try:
            self.hal.connect(full, net)
        except Exception as exc:
            raise Refused(f"cannot join {full} to signal {net!r}: {exc}", "bad_address",
                          name) from exc

    def _free_writer(self, net: str) -> None:
        """A signal compd drives that a pin of a dead component of ours (a HAL side
        killed with SIGKILL) still drives: unlink that pin (the signal keeps its
        value) so that ours can drive it. The pin's owner is told by the component
        id HAL reports, never by the pin's name: any other writer is left alone (the
        join then fails, naming the signal)."""
        if not self._dead:
            return
        sig = next((s for s in self.hal.get_info_signals() if s["NAME"] == net), None)
        writer = str(sig.get("DRIVER") or "") if sig is not None else ""
        if writer and any(owner in self._dead for owner, pin in _pins(writer)
                          if pin == writer):
            self.hal.disconnect(writer)

    # -- read -------------------------------------------------------------------

    def read(self, names: list[str]) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for name in names:
            p = self.pins.get(name)
            if p is not None:
                v = self.comp[p["pin"]]
                out[name] = float((not v) if p.get("invert") else v)
            elif name in self.gets:
                what, scale, invert = self.gets[name]
                try:
                    raw = self.hal.get_value(what)
                    out[name] = float((not raw) if invert else raw) * scale
                except Exception as exc:
                    raise Refused(f"no HAL item {what!r}: {exc}", "bad_address", name) from exc
            elif name in self.eos:
                eo = self.eos[name]
                out[name] = (self._offset(eo["axis"]) / self.eoffset_scales[name]
                             * eo["scale"])
            else:
                raise Refused("unknown channel or output name", "bad_address", name)
        return out

    def _offset(self, axis: str) -> float:
        """The offset LinuxCNC holds (machine units): what motion applies
        (``axis.L.eoffset``), or, while motion clips it at a soft limit
        (``motion.eoffset-limited``), what it was asked for (``eoffset-request``):
        the clipped part is LinuxCNC's limit, not another writer's offset."""
        try:
            limited = bool(self.hal.get_value("motion.eoffset-limited"))
        except Exception:  # a LinuxCNC without the pin: what motion applies
            limited = False
        what = "eoffset-request" if limited else "eoffset"
        return float(self.hal.get_value(f"axis.{axis}.{what}"))

    # -- write ------------------------------------------------------------------

    def write(self, values: dict[str, float]) -> None:
        # the pins first: a refused offset (machine off) still lets the heartbeat
        # and the status word through
        offsets: dict[str, float] = {}
        for name, value in values.items():
            p = self.pins.get(name)
            if p is not None:
                if p["dir"] != "out":
                    raise Refused("not an output", "bad_address", name)
                t = p["type"]
                self.comp[p["pin"]] = (bool(value) != bool(p.get("invert")) if t == "bit"
                                       else float(value) if t == "float" else round(value))
            elif name in self.eos:
                offsets[name] = float(value)
            else:
                raise Refused("unknown output name (not writable)", "bad_address", name)
        if offsets:
            self._write_offsets(offsets)

    def _accepting(self) -> str | None:
        """Why LinuxCNC takes no offset change now, None when it does."""
        get = self.hal.get_value
        if not get("motion.motion-enabled"):
            return "machine off (or E-stop)"
        if not get("motion.is-all-homed"):
            return "machine not homed"
        return None

    def _requested(self, name: str) -> int:
        """The counts axis.L.eoffset-request of offset `name` holds now."""
        axis = self.eos[name]["axis"]
        now = float(self.hal.get_value(f"axis.{axis}.eoffset-request"))
        return round(now / self.eoffset_scales[name])

    def _write_offsets(self, values: dict[str, float]) -> None:
        """Each offset's change of counts, made together, then waited for together."""
        first = min(values)
        why = self._accepting()
        if why is not None:
            self.expect.clear()  # a change not taken before the machine went off is lost
            raise Refused(f"LinuxCNC takes no external offset now: {why}", "rejected", first)
        wanted: dict[str, int] = {}
        for name, value in sorted(values.items()):
            eo = self.eos[name]
            want = round(value / eo["scale"])
            held = self._requested(name)
            expect = self.expect.pop(name, None)
            if expect is not None and held != expect:
                held = expect  # our last change is still on its way: LinuxCNC will hold it
            delta = want - held
            if delta == 0:
                continue
            pin = eo["counts_pin"]
            self.comp[pin] = int(self.comp[pin]) + delta
            self.expect[name] = want
            wanted[name] = want
        # the servo thread adds the changes within a period: wait until it has, so
        # that the write reports what LinuxCNC took
        deadline = time.monotonic() + self.wait_s
        while wanted:
            for name in [n for n, w in wanted.items() if self._requested(n) == w]:
                del wanted[name]
                del self.expect[name]
            if not wanted:
                return
            if self._accepting() is not None:
                self.expect.clear()
                raise Refused("LinuxCNC stopped taking the external offset during the write",
                              "rejected", min(wanted))
            if time.monotonic() > deadline:
                # a servo thread late (a loaded machine without a realtime kernel): a
                # transient refusal, the link stays; the next write counts from `expect`
                raise Refused(f"LinuxCNC's servo thread did not take the offset within "
                              f"{self.wait_s:g} s", "rejected", min(wanted))
            time.sleep(0.0002)


class _Comp(NamedTuple):
    cid: int
    name: str
    user: bool
    pid: int


def _halcmd(*args: str) -> str:
    return subprocess.run(["halcmd", *args], capture_output=True, text=True, timeout=30,
                          check=False).stdout


def _components() -> dict[str, _Comp]:
    """HAL's components by name (``halcmd show comp``: id, type, name, process)."""
    found: dict[str, _Comp] = {}
    for line in _halcmd("-s", "show", "comp").splitlines():
        f = line.split()
        if len(f) >= 3 and f[0].isdigit() and f[1] in ("User", "RT"):
            user = f[1] == "User"
            pid = int(f[3]) if user and len(f) >= 4 and f[3].isdigit() else 0
            found[f[2]] = _Comp(int(f[0]), f[2], user, pid)
    return found


def _pins(prefix: str) -> list[tuple[int, str]]:
    """The pins and parameters whose names begin with `prefix`, with their owners'
    component ids (``halcmd show pin/param``: the owner's id in the first column)."""
    out: list[tuple[int, str]] = []
    for what, at in (("pin", 4), ("param", 4)):
        for line in _halcmd("show", what, prefix).splitlines():
            f = line.split()
            if len(f) > at and f[0].isdigit() and f[at].startswith(prefix):
                out.append((int(f[0]), f[at]))
    return out


def _family(name: str, base: str) -> bool:
    """`name` is `base` or a restart's ``base-<n>``."""
    return name == base or re.fullmatch(re.escape(base) + r"-[0-9]+", name) is not None


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _serve(comp: Component) -> None:
    for line in sys.stdin:
        try:
            req = json.loads(line)
            if "r" in req:
                _answer({"v": comp.read(req["r"])})
            else:
                comp.write(req["w"])
                _answer({"ok": 1})
        except Refused as exc:
            _answer({"e": str(exc), "k": exc.kind, "n": exc.name})
        except Exception as exc:  # HAL gone under us: the driver drops the link
            _answer({"e": f"{type(exc).__name__}: {exc}", "k": "lost", "n": None})


def main() -> int:
    # halcmd unload (LinuxCNC's shutdown) sends SIGTERM: leave quietly, HAL
    # removes the component and the driver sees end-of-file
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    try:
        hal = importlib.import_module("hal")
    except ImportError as exc:
        _answer({"e": f"no LinuxCNC 'hal' module for {sys.executable}: {exc}",
                 "k": "unavailable", "n": None})
        return 3
    try:
        comp = Component(hal, json.loads(sys.argv[1]))
    except Refused as exc:
        _answer({"e": str(exc), "k": exc.kind, "n": exc.name})
        return 2
    except Exception as exc:  # HAL refused a pin (its stderr says why), or went away
        _answer({"e": f"{type(exc).__name__}: {exc}", "k": "lost", "n": None})
        return 2
    _answer({"ready": 1, "eoffset_scales": comp.eoffset_scales})
    with contextlib.suppress(KeyboardInterrupt):
        _serve(comp)
    return 0


if __name__ == "__main__":
    sys.exit(main())
