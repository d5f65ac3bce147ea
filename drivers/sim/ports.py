"""Free loopback ports for simulated controllers, and starting on one.

A port found free is free only "a moment ago": binding port 0 and closing it
hands out a port of the kernel's ephemeral range, the same range every outgoing
connection on the machine takes its source port from. Between the pick and the
server's own bind another connection (another test worker's client, say) may
take it, and the bind fails with EADDRINUSE. A simulated controller whose port
was picked here therefore picks again and binds again (`start_on_free_port`); a
port its caller named is never changed.
"""

from __future__ import annotations

import errno
import socket
from collections.abc import Awaitable, Callable

#: binds tried before a picked port's failure is the caller's
TRIES = 5


def free_tcp_port(host: str = "127.0.0.1") -> int:
    """A TCP port that was free on `host` a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        port: int = s.getsockname()[1]
        return port


def address_in_use(exc: BaseException) -> bool:
    """Whether `exc` says the port was taken: EADDRINUSE itself, or a library's
    own error that carries its text (python-snap7 and pymodbus drop the errno)."""
    if isinstance(exc, OSError) and exc.errno == errno.EADDRINUSE:
        return True
    return "address already in use" in str(exc).lower()


async def start_on_free_port(start: Callable[[], Awaitable[None]],
                             repick: Callable[[], None], *, picked: bool,
                             taken: Callable[[BaseException], bool] = address_in_use) -> None:
    """`start()`; when it fails because the port was taken (`taken`) and the port
    was picked by `free_tcp_port` (`picked`), `repick()` sets another and it is
    started again, at most `TRIES` times in all."""
    for attempt in range(TRIES):
        try:
            await start()
            return
        except Exception as exc:
            if not picked or attempt == TRIES - 1 or not taken(exc):
                raise
            repick()
