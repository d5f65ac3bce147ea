"""The simulated machines' former channel names, still read for a while.

The bench machine called its spindle speed ``speed_rpm`` and the shop machine
its temperatures ``t01_degC`` … ``t09_degC``; both now use the real record's
names (``spindle_rpm``, ``t1_degC`` … ``t16_degC``, tests/data/fl_thermal).
Records, drive maps and configs written before keep working: where a former
name is met, it is read as the current one and one line on stderr, once per
process and name, says which name to use (`warn_former`).
"""

from __future__ import annotations

import sys

#: former name -> current name
FORMER_NAMES: dict[str, str] = {
    "speed_rpm": "spindle_rpm",
    **{f"t0{i}_degC": f"t{i}_degC" for i in range(1, 10)},
}

_warned: set[str] = set()


def current_name(name: str) -> str:
    """The current name of a former one; any other name as it is."""
    return FORMER_NAMES.get(name, name)


def counterpart(name: str) -> str | None:
    """The other spelling of a renamed channel (current for a former name, former for
    a current one), or None for a name never renamed."""
    if name in FORMER_NAMES:
        return FORMER_NAMES[name]
    for old, new in FORMER_NAMES.items():
        if new == name:
            return old
    return None


def warn_former(old: str, where: str) -> None:
    """Say once per process (per former name) that `old` is taken for its current name;
    `where` names the file or the input it came from."""
    if old in _warned:
        return
    _warned.add(old)
    new = FORMER_NAMES[old]
    print(f"compd: warning: {where}: {old!r} is the former name of {new!r} and is taken "
          f"for it; use {new!r} (a later version will not take {old!r})", file=sys.stderr)
