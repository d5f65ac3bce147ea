"""What a record's column measures, told from its name: the one rule.

A calibration record (CSV, or the recorder's database read as a record)
carries names, not units. Fit, replay, the figures and the record checks
each need to know whether a column is a temperature (°C: enters a model
relative to its first sample, plotted on the temperature axis, checked for a
mK slip) or a rate that heats the machine (spindle speed, drive power:
enters as it is, plotted on its own axis). One function answers for all:

- SPEED: the name contains ``speed`` or ``rpm`` (``spindle_rpm``,
  ``SpindleSpeed``, ``rpm_s1``);
- POWER: the name contains ``power`` or has ``kW`` as a word of its own
  (``power_kw``, ``p_kw``, ``kw_drive``);
- TEMPERATURE: everything else (``bearing``, ``t1_degC``, ``ambient``).

Case does not matter; words are separated by anything but letters and digits.
The daemon never guesses: its channels carry units (`[channels.*] unit`).
"""

from __future__ import annotations

import enum
import re
from collections.abc import Iterable

__all__ = ["ChannelKind", "channel_kind", "is_rate_channel", "step_unit"]

_WORDS = re.compile(r"[^a-z0-9]+")


class ChannelKind(enum.StrEnum):
    TEMPERATURE = "temperature"
    SPEED = "speed"
    POWER = "power"


def channel_kind(name: str) -> ChannelKind:
    """The kind of the column `name` (see the module docstring)."""
    low = name.lower()
    if "speed" in low or "rpm" in low:
        return ChannelKind.SPEED
    if "power" in low or "kw" in _WORDS.split(low):
        return ChannelKind.POWER
    return ChannelKind.TEMPERATURE


def is_rate_channel(name: str) -> bool:
    """A speed or a power: it enters a model as it is, not relative to its
    first sample (only temperatures have a reference)."""
    return channel_kind(name) is not ChannelKind.TEMPERATURE


def step_unit(inputs: Iterable[str], relative: bool) -> str:
    """The unit of one step of a term's input: K for a temperature term (it
    enters relative to its reference), rpm for a speed, kW for a power, else
    "unit of a+b" (a combination of rates of different kinds)."""
    if relative:
        return "K"
    names = list(inputs)
    kinds = {channel_kind(ch) for ch in names}
    if kinds == {ChannelKind.SPEED}:
        return "rpm"
    if kinds == {ChannelKind.POWER}:
        return "kW"
    return "unit of " + "+".join(names)
