"""LinuxCNC's addresses and its ``[controller.linuxcnc]`` options (pydantic only;
the address models live with every protocol's in `drivers.addresses`).

compd is a HAL user-space component (`drivers.linuxcnc`), named
``component`` (``compd``). Two kinds of address:

- ``pin`` (the default): compd's own pin ``<component>.<pin>``, joined at
  connect to the HAL signal ``net`` that the machine's HAL file makes with a
  ``net`` line (a channel: an input pin the sensor's signal drives; an
  output: an output pin driving the signal). Engineering value = HAL value ×
  ``scale``; a ``bit`` may be inverted (``estop:loop`` is true when out of
  E-stop).
- ``eoffset``: an axis' external offset. compd drives the signals
  ``counts_net`` (to ``axis.L.eoffset-counts``) and ``enable_net`` (to
  ``axis.L.eoffset-enable``) and reads back ``axis.L.eoffset``; the value is
  counts × ``scale`` (controller units per count), and ``eoffset_scale``,
  when given, must equal ``axis.L.eoffset-scale`` (machine units per count).
  One per axis (X, Y, Z... each with signals of its own), outputs only.
- ``get`` (read only): any HAL pin or signal by name (``motion.motion-enabled``),
  read as ``halcmd getp`` does, without a ``net`` line.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field, field_validator

from drivers.addresses import (
    HalName,
    LinuxCncAddress,
    LinuxCncEoffset,
    LinuxCncGet,
    LinuxCncPin,
    hal_name,
)

#: HAL's longest name (HAL_NAME_LEN): a pin ``<component>.<pin>`` longer than this
#: cannot be created
HAL_NAME_LEN = 47
#: the most components a killed HAL side may leave behind (HAL frees a user
#: component only when its process calls hal_exit, so one killed with SIGKILL stays
#: until LinuxCNC restarts): the next start takes ``<component>-2`` up to
#: ``<component>-<MAX_LEFT_BEHIND + 1>``, then refuses, naming them
MAX_LEFT_BEHIND = 20
#: the longest suffix a restarted HAL side adds to the component's name
RESTART_SUFFIX = f"-{MAX_LEFT_BEHIND + 1}"
#: the pins compd makes for Z's external offset (`drivers.linuxcnc`; another axis's:
#: `LinuxCncEoffset.pins`)
EOFFSET_PINS = ("eoffset-counts", "eoffset-enable")
#: names of LinuxCNC's own components and of the pins it makes (motion's
#: ``spindle.0.speed-out``, ``axis.z.eoffset``...): a compd component of such a name
#: would stand among LinuxCNC's pins (compared without case, on the name's first
#: dotted part)
LINUXCNC_NAMES = frozenset({
    "motion", "motmod", "spindle", "axis", "joint", "iocontrol", "halui", "tp", "tpmod",
    "homemod", "trivkins", "kins", "ini", "inihal", "halcmd", "io", "iov2", "emcmot",
    "hal_manualtoolchange", "classicladder", "pid", "stepgen", "encoder", "pwmgen",
    "siggen", "parport", "threads", "servo-thread", "base-thread"})


def linuxcnc_name_clash(component: str) -> str | None:
    """Why `component` cannot be compd's HAL component name (one of LinuxCNC's
    own), None when it can."""
    head = component.split(".", 1)[0].lower()
    if head in LINUXCNC_NAMES:
        return (f"{component!r} is a name LinuxCNC uses for its own components and pins "
                f"({head}.*): choose another, e.g. 'compd'")
    return None


def pin_names(addresses: Mapping[str, object]) -> dict[str, str]:
    """The pins compd makes for `addresses` (name -> pin, the offset's two pins
    under the offset's name)."""
    pins: dict[str, str] = {}
    for name, a in addresses.items():
        if isinstance(a, LinuxCncPin):
            pins[name] = a.pin
        elif isinstance(a, LinuxCncEoffset):
            pins[name] = max(a.pins, key=len)
    return pins


def long_hal_name(component: str, addresses: Mapping[str, object]) -> tuple[str, str] | None:
    """The first address whose pin name, as a restarted HAL side would make it
    (``<component>-<n>.<pin>``), is longer than HAL allows: (address name, reason);
    None when every one fits."""
    for name, pin in pin_names(addresses).items():
        full = f"{component}{RESTART_SUFFIX}.{pin}"
        if len(full) > HAL_NAME_LEN:
            return name, (f"the HAL pin {component}.{pin} is too long: HAL allows "
                          f"{HAL_NAME_LEN} characters and a restarted component "
                          f"({full}) takes {len(full)}; shorten the pin or "
                          f"controller.linuxcnc.component")
    return None


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)


class LinuxCncOptions(_Model):
    """``[controller.linuxcnc]``: the HAL component's name and the Python that
    runs its HAL side (the one LinuxCNC's ``hal`` module was built for)."""

    component: HalName = "compd"
    python: Annotated[str, Field(min_length=1)] = "/usr/bin/python3"

    _names = field_validator("component")(hal_name)

    @field_validator("component")
    @classmethod
    def _not_linuxcncs(cls, v: str) -> str:
        why = linuxcnc_name_clash(v)
        if why is not None:
            raise ValueError(why)
        if len(v) + len(RESTART_SUFFIX) > HAL_NAME_LEN:
            raise ValueError(f"at most {HAL_NAME_LEN - len(RESTART_SUFFIX)} characters "
                             f"(a restarted HAL side adds up to {RESTART_SUFFIX!r})")
        return v

    @field_validator("python")
    @classmethod
    def _absolute(cls, v: str) -> str:
        if not v.startswith("/"):
            raise ValueError("must be an absolute path (the system Python LinuxCNC's hal "
                             "module was built for, e.g. /usr/bin/python3)")
        return v

    def driver_options(self) -> dict[str, str]:
        return {"component": self.component, "python": self.python}


__all__ = ["EOFFSET_PINS", "HAL_NAME_LEN", "MAX_LEFT_BEHIND", "LinuxCncAddress",
           "LinuxCncEoffset", "LinuxCncGet", "LinuxCncOptions", "LinuxCncPin",
           "linuxcnc_name_clash", "long_hal_name", "pin_names"]
