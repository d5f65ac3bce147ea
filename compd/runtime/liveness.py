"""Evidence that the daemon works, readable by another process (`compd health`).

The checkpoint carries the time of the last complete cycle twice: on the wall
clock and on the monotonic clock, with the kernel's boot id. The monotonic
clock is shared by every process of one boot (containers included) and never
jumps, so a health check of the same boot judges the age on it; after a
reboot (another boot id) only the wall clock is left, and a stamp in the
future then means a clock that was stepped back: not evidence of anything.

Only the standard library: `compd health` imports this and must stay cheap.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from typing import Any

__all__ = ["FUTURE_SLACK_S", "boot_id", "last_complete_age_s"]

BOOT_ID_PATH = "/proc/sys/kernel/random/boot_id"
#: a wall stamp this far ahead of now is a clock stepped back, not a fresh cycle
FUTURE_SLACK_S = 5.0


#: the boot id read from each path (a process never outlives its boot: every
#: checkpoint of a fleet stamps it, and reading the file was a fleet's share)
_BOOT_IDS: dict[str, str | None] = {}


def boot_id() -> str | None:
    """The kernel's boot id (None where there is none, e.g. not Linux); read once
    per process."""
    path = BOOT_ID_PATH
    if path in _BOOT_IDS:
        return _BOOT_IDS[path]
    try:
        with open(path, encoding="ascii") as f:
            found = f.read(64).strip() or None
    except (OSError, UnicodeDecodeError):
        return None  # not kept: a read that failed once may succeed later
    _BOOT_IDS[path] = found
    return found


def _finite(x: Any) -> float | None:
    if isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x):
        return float(x)
    return None


def last_complete_age_s(state: Mapping[str, Any]) -> tuple[float | None, str]:
    """Seconds since the last complete cycle recorded in a checkpoint `state`,
    and how it was judged; None with the reason when there is no evidence."""
    wall = _finite(state.get("last_complete_wall_s"))
    mono = _finite(state.get("last_complete_mono_s"))
    if wall is None:
        return None, "no complete cycle recorded"
    same_boot = state.get("boot_id") is not None and state.get("boot_id") == boot_id()
    if same_boot and mono is not None:
        age = time.monotonic() - mono
        if age >= 0.0:
            return age, "monotonic clock"
    age = time.time() - wall
    if age < -FUTURE_SLACK_S:
        return None, f"last complete cycle stamped {-age:.0f} s in the future (clock stepped?)"
    return max(0.0, age), "wall clock"
