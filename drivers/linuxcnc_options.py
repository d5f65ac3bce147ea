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
- ``get`` (read only): any HAL pin or signal by name (``motion.motion-enabled``),
  read as ``halcmd getp`` does, without a ``net`` line.
"""

from __future__ import annotations

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


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)


class LinuxCncOptions(_Model):
    """``[controller.linuxcnc]``: the HAL component's name and the Python that
    runs its HAL side (the one LinuxCNC's ``hal`` module was built for)."""

    component: HalName = "compd"
    python: Annotated[str, Field(min_length=1)] = "/usr/bin/python3"

    _names = field_validator("component")(hal_name)

    @field_validator("python")
    @classmethod
    def _absolute(cls, v: str) -> str:
        if not v.startswith("/"):
            raise ValueError("must be an absolute path (the system Python LinuxCNC's hal "
                             "module was built for, e.g. /usr/bin/python3)")
        return v

    def driver_options(self) -> dict[str, str]:
        return {"component": self.component, "python": self.python}


__all__ = ["LinuxCncAddress", "LinuxCncEoffset", "LinuxCncGet", "LinuxCncOptions",
           "LinuxCncPin"]
