"""How many connections a listener of this process may hold: the soft RLIMIT_NOFILE
minus the descriptors open now, a reserve for everything else, and one accept burst."""

from __future__ import annotations

import os
import resource

#: descriptors kept for everything but the face (cycle, checkpoints, recorder,
#: /metrics and the status page, controller reconnects, other machines of `run DIR`)
FD_RESERVE = 256
#: connections the listener accepts per wake (asyncio's backlog), and its listen queue
ACCEPT_BURST = 16


def open_fds() -> int:
    """Descriptors open in this process now (0 where /proc is not there)."""
    try:
        return len(os.listdir("/proc/self/fd"))
    except OSError:
        return 0


def fd_budget(soft_limit: int, open_now: int, reserve: int = FD_RESERVE,
              burst: int = ACCEPT_BURST) -> int:
    """Connections the face may hold: `soft_limit` (RLIMIT_NOFILE; negative:
    unlimited) minus what is open, the reserve and one accept burst. Example:
    1024 - 40 - 256 - 16 = 712."""
    if soft_limit < 0:
        return 1 << 30
    return soft_limit - open_now - reserve - burst


def nofile_soft_limit() -> int:
    soft, _hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    return -1 if soft == resource.RLIM_INFINITY else int(soft)

