"""The signals compd answers, one list for `compd run CONFIG` and `compd run DIR`.

A signal whose default action ends the process ends it at once: no log line, no
checkpoint, no shutdown policy, the offset left where it was. So every one that
can arrive from outside is handled:

- stop, as SIGTERM (finish the cycle, shutdown policy, checkpoint, exit 0; the
  signal named in the log): SIGTERM, SIGINT, and SIGALRM, SIGVTALRM, SIGPROF,
  SIGIO, SIGPWR (a UPS), SIGXCPU (a CPU-time limit: what RLIMIT_CPU and
  systemd's LimitCPU= send), SIGSTKFLT;
- reload: SIGHUP;
- logged and otherwise ignored: SIGUSR1, SIGUSR2 (no meaning here), SIGXFSZ (a
  file-size limit: the write that crossed it fails with EFBIG instead, which the
  recorder or the checkpoint reports, and compensation goes on).

Left alone: SIGKILL and SIGSTOP (cannot be caught), SIGQUIT (an operator's
request for a core dump), SIGPIPE (Python ignores it), and the signals a fault
of the process itself raises (SIGSEGV, SIGBUS, SIGILL, SIGFPE, SIGABRT, SIGSYS,
SIGTRAP): the process cannot go on after those.
"""

from __future__ import annotations

import asyncio
import signal
from collections.abc import Callable

__all__ = ["IGNORED", "STOP", "install"]


def _present(*names: str) -> tuple[signal.Signals, ...]:
    """The named signals this platform has (SIGPWR, SIGSTKFLT are Linux's)."""
    return tuple(getattr(signal, n) for n in names if hasattr(signal, n))


#: handled like SIGTERM
STOP: tuple[signal.Signals, ...] = _present(
    "SIGTERM", "SIGINT", "SIGALRM", "SIGVTALRM", "SIGPROF", "SIGIO", "SIGPWR", "SIGXCPU",
    "SIGSTKFLT")
#: logged (``signal_ignored``) and otherwise ignored
IGNORED: tuple[signal.Signals, ...] = _present("SIGUSR1", "SIGUSR2", "SIGXFSZ")


def install(loop: asyncio.AbstractEventLoop, *, stop: Callable[[signal.Signals], None],
            reload: Callable[[], None],
            ignored: Callable[[signal.Signals], None]) -> list[signal.Signals]:
    """Install the handlers on `loop`; returns the signals installed (none when not
    in the main thread: the caller then stops the daemon with its request_stop)."""
    handlers: list[tuple[signal.Signals, Callable[[], None]]] = [
        (signal.SIGHUP, reload)]
    handlers += [(s, _bind(stop, s)) for s in STOP]
    handlers += [(s, _bind(ignored, s)) for s in IGNORED]
    installed: list[signal.Signals] = []
    for sig, handler in handlers:
        try:
            loop.add_signal_handler(sig, handler)
        except (RuntimeError, ValueError, NotImplementedError):
            continue
        installed.append(sig)
    return installed


def remove(loop: asyncio.AbstractEventLoop, installed: list[signal.Signals]) -> None:
    """Undo `install`."""
    for sig in installed:
        loop.remove_signal_handler(sig)


def _bind(fn: Callable[[signal.Signals], None], sig: signal.Signals) -> Callable[[], None]:
    def handler() -> None:
        fn(sig)

    return handler
