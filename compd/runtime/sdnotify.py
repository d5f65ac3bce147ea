"""systemd's notify protocol (Type=notify, WatchdogSec=), without libsystemd.

Each message is one datagram of ``KEY=value`` lines sent over an AF_UNIX
SOCK_DGRAM socket to ``$NOTIFY_SOCKET`` (a path, or an abstract-namespace name
when it starts with "@"). Outside systemd there is no socket: the notifier is
disabled and every call does nothing. A send that fails (systemd gone, a full
socket buffer) is counted in `errors`, kept in `last_error`, and never raised:
compensation does not stop for a missing service manager. The socket is
non-blocking, so a stuck receiver never delays a cycle.

The daemon sends READY=1 after its loop's first cycle, whether the controller
answered or not (a controller that is off when the PC boots is retried with
the backoff, and health says why nothing is in force), WATCHDOG=1 on every
cycle after that while the loop is alive (a broken sensor or a lost link is
the fault policy's business: hold, then ramp with the alarm; a restart by
systemd would mend neither and would reset the hold timer), STATUS= with
the current offset and state, STOPPING=1 on shutdown.
"""

from __future__ import annotations

import contextlib
import os
import socket
from collections.abc import Mapping

__all__ = ["FROM_ENVIRONMENT", "Notifier", "watchdog_interval_s"]

#: Default of `Notifier(socket_path)`: read $NOTIFY_SOCKET when the notifier is made.
#: (A NUL-prefixed text no one passes as a path; compared by value.)
FROM_ENVIRONMENT = "\x00$NOTIFY_SOCKET"


def watchdog_interval_s(environ: Mapping[str, str] | None = None, pid: int | None = None
                        ) -> float | None:
    """systemd's watchdog period (s) from WATCHDOG_USEC, None when there is
    none or when WATCHDOG_PID names another process."""
    env = os.environ if environ is None else environ
    usec = env.get("WATCHDOG_USEC")
    if not usec:
        return None
    owner = env.get("WATCHDOG_PID")
    if owner:
        try:
            if int(owner) != (os.getpid() if pid is None else pid):
                return None
        except ValueError:
            return None
    try:
        value = int(usec)
    except ValueError:
        return None
    return value / 1e6 if value > 0 else None


class Notifier:
    """Sends notify messages to systemd; silent and disabled without a socket."""

    def __init__(self, socket_path: str | None = FROM_ENVIRONMENT) -> None:
        if socket_path == FROM_ENVIRONMENT:
            socket_path = os.environ.get("NOTIFY_SOCKET")
        self.socket_path = socket_path or None
        self.sent = 0
        self.errors = 0
        self.last_error: str | None = None
        self._address: str | None = None
        if self.socket_path is not None:
            path = self.socket_path
            self._address = "\0" + path[1:] if path.startswith("@") else path
        self._sock: socket.socket | None = None

    @property
    def enabled(self) -> bool:
        return self._address is not None

    def notify(self, message: str) -> bool:
        """Send one datagram; True when it was handed to the kernel. Never raises."""
        if self._address is None:
            return False
        try:
            if self._sock is None:
                sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
                sock.setblocking(False)
                self._sock = sock
            self._sock.sendto(message.encode("utf-8", "replace"), self._address)
        except (OSError, ValueError) as exc:
            self.errors += 1
            self.last_error = f"{type(exc).__name__}: {exc}"
            return False
        self.sent += 1
        return True

    def ready(self) -> None:
        self.notify(f"READY=1\nMAINPID={os.getpid()}")

    def watchdog(self) -> None:
        self.notify("WATCHDOG=1")

    def status(self, text: str) -> None:
        """One-line status for `systemctl status` (newlines become spaces)."""
        self.notify("STATUS=" + " ".join(text.splitlines()))

    def stopping(self) -> None:
        self.notify("STOPPING=1")

    def watchdog_interval_s(self) -> float | None:
        """See the module function `watchdog_interval_s`."""
        return watchdog_interval_s()

    def close(self) -> None:
        sock, self._sock = self._sock, None
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.close()

    def __del__(self) -> None:
        self.close()
