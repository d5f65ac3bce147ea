"""Drive a headless LinuxCNC through its ``linuxcnc`` Python module (NML).

Run as ``python3 -I linuxcnc_ctl.py COMMAND [ARG]`` under the system Python
that LinuxCNC's module was built for (the test machine's side, never
imported by compd); prints one JSON line (``linuxcnc.stat()`` as it is after
the command, with the messages LinuxCNC queued on its error channel) and
exits 0, or prints ``{"e": message}`` and exits 1.

Commands: ``stat``; ``on`` (out of E-stop, machine on, manual mode, home
every joint, wait until homed); ``off`` (machine off); ``estop``; ``run
FILE`` (auto mode, open FILE, run it from its first line); ``abort``;
``unhome`` (abort, joint mode, un-home every joint); ``mdi LINE`` (abort, MDI
mode, run LINE to its end).
"""

from __future__ import annotations

import importlib
import json
import sys
import time
from typing import Any

#: the longest a command may take before it is reported as failed (s)
DEADLINE_S = 60.0


def _errors(lc: Any) -> list[str]:
    """The operator messages and errors LinuxCNC queued since the last read (its
    error channel is a queue: read here, they are gone for other readers)."""
    channel, got = lc.error_channel(), []
    for _ in range(32):
        message = channel.poll()
        if not message:
            break
        got.append(str(message[1]))
    return got


def _stat(lc: Any, s: Any) -> dict[str, Any]:
    s.poll()
    return {"errors": _errors(lc), "task_state": s.task_state, "estop": bool(s.estop),
            "machine_on": s.task_state == lc.STATE_ON, "homed": list(s.homed[:s.joints]),
            "interp_state": s.interp_state, "exec_state": s.exec_state,
            "task_mode": s.task_mode, "z_mm": s.actual_position[2],
            "eoffset_z_mm": s.external_offsets[2] if hasattr(s, "external_offsets") else None,
            "spindle_rpm": s.spindle[0]["speed"] if s.spindle else 0.0}


def _until(s: Any, ok: Any, what: str) -> None:
    deadline = time.monotonic() + DEADLINE_S
    while True:
        s.poll()
        if ok():
            return
        if time.monotonic() > deadline:
            raise RuntimeError(f"LinuxCNC did not {what} within {DEADLINE_S:g} s")
        time.sleep(0.02)


def main(argv: list[str]) -> int:
    try:
        lc = importlib.import_module("linuxcnc")
        s, c = lc.stat(), lc.command()
        s.poll()
        cmd = argv[1]
        if cmd == "on":
            c.state(lc.STATE_ESTOP_RESET)
            c.wait_complete()
            c.state(lc.STATE_ON)
            c.wait_complete()
            _until(s, lambda: s.task_state == lc.STATE_ON, "switch on")
            c.mode(lc.MODE_MANUAL)
            c.wait_complete()
            c.home(-1)
            c.wait_complete()
            _until(s, lambda: all(s.homed[:s.joints]), "home")
        elif cmd == "off":
            c.state(lc.STATE_OFF)
            c.wait_complete()
            _until(s, lambda: s.task_state != lc.STATE_ON, "switch off")
        elif cmd == "estop":
            c.state(lc.STATE_ESTOP)
            c.wait_complete()
            _until(s, lambda: s.task_state == lc.STATE_ESTOP, "go to E-stop")
        elif cmd == "run":
            c.mode(lc.MODE_AUTO)
            c.wait_complete()
            c.program_open(argv[2])
            c.auto(lc.AUTO_RUN, 0)
            _until(s, lambda: s.interp_state != lc.INTERP_IDLE, "start the program")
        elif cmd == "abort":
            c.abort()
            c.wait_complete()
        elif cmd == "unhome":  # stop a program, joint mode, every joint un-homed
            c.abort()
            c.wait_complete()
            c.mode(lc.MODE_MANUAL)
            c.wait_complete()
            c.teleop_enable(0)
            c.wait_complete()
            c.unhome(-1)
            c.wait_complete()
            _until(s, lambda: not any(s.homed[:s.joints]), "un-home")
        elif cmd == "mdi":  # stop a program, run one MDI line to its end
            c.abort()
            c.wait_complete()
            c.mode(lc.MODE_MDI)
            c.wait_complete()
            c.mdi(argv[2])
            c.wait_complete(DEADLINE_S)
        elif cmd != "stat":
            raise ValueError(f"unknown command {cmd!r}")
        print(json.dumps(_stat(lc, s)))
        return 0
    except Exception as exc:
        print(json.dumps({"e": f"{type(exc).__name__}: {exc}"}))
        return 1


if __name__ == "__main__":
    sys.exit(main(sys.argv))
