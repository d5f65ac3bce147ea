"""LinuxCNC's addresses and its ``[controller.linuxcnc]`` options (pydantic only).

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

import math
import re
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

#: a HAL name: letters, digits and ``.-_:`` (HAL_NAME_LEN is 47)
_HAL_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.:\-]{0,46}")
HalName = Annotated[str, Field(min_length=1, max_length=47)]


def _hal_name(v: str) -> str:
    if not _HAL_NAME.fullmatch(v):
        raise ValueError(f"not a HAL name: {v!r} (letters, digits, '.', '-', '_', ':'; "
                         "at most 47 characters)")
    return v


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)


class LinuxCncPin(_Model):
    """compd's own HAL pin joined to the signal ``net`` (see the module)."""

    kind: Literal["pin"] = "pin"
    pin: HalName
    net: HalName
    type: Literal["float", "s32", "u32", "bit"] = "float"
    scale: float = 1.0
    invert: bool = False

    _names = field_validator("pin", "net")(_hal_name)

    @field_validator("scale")
    @classmethod
    def _scale(cls, v: float) -> float:
        if not math.isfinite(v) or v == 0.0:
            raise ValueError("scale must be a finite non-zero number")
        return v

    @model_validator(mode="after")
    def _invert_bits(self) -> LinuxCncPin:
        if self.invert and self.type != "bit":
            raise ValueError("invert is for a bit pin only")
        return self

    def describe(self) -> str:
        return f"{self.pin}<->{self.net}:{self.type}"


class LinuxCncEoffset(_Model):
    """An axis' external offset in counts (see the module)."""

    kind: Literal["eoffset"]
    axis: Literal["x", "y", "z", "a", "b", "c", "u", "v", "w"] = "z"
    counts_net: HalName = "compd-eoffset-counts"
    enable_net: HalName = "compd-eoffset-enable"
    #: controller units per count (the output's unit: um with 1 µm counts -> 1.0)
    scale: float = 1.0
    #: axis.L.eoffset-scale as the HAL file sets it (machine units per count); checked
    eoffset_scale: float | None = None
    #: the type compd's count arithmetic sees (whole counts)
    type: Literal["s32"] = "s32"

    _names = field_validator("counts_net", "enable_net")(_hal_name)

    @field_validator("scale", "eoffset_scale")
    @classmethod
    def _scale(cls, v: float | None) -> float | None:
        if v is not None and (not math.isfinite(v) or v <= 0.0):
            raise ValueError("must be a finite positive number")
        return v

    def describe(self) -> str:
        return f"axis.{self.axis}.eoffset-counts<-{self.counts_net}"


class LinuxCncGet(_Model):
    """Read only: any HAL pin, signal or parameter by its name, as ``halcmd
    getp`` reads it (``motion.motion-enabled``, ``axis.z.eoffset``), × ``scale``
    (a bit: 0 or 1, inverted with ``invert``). No ``net`` line needed."""

    kind: Literal["get"]
    hal: HalName
    scale: float = 1.0
    invert: bool = False

    _names = field_validator("hal")(_hal_name)

    @field_validator("scale")
    @classmethod
    def _scale(cls, v: float) -> float:
        if not math.isfinite(v) or v == 0.0:
            raise ValueError("scale must be a finite non-zero number")
        return v

    def describe(self) -> str:
        return f"getp {self.hal}"


LinuxCncAddress = LinuxCncPin | LinuxCncEoffset | LinuxCncGet


class LinuxCncOptions(_Model):
    """``[controller.linuxcnc]``: the HAL component's name and the Python that
    runs its HAL side (the one LinuxCNC's ``hal`` module was built for)."""

    component: HalName = "compd"
    python: Annotated[str, Field(min_length=1)] = "/usr/bin/python3"

    _names = field_validator("component")(_hal_name)

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
