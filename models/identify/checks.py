"""Checks every fitted transfer function passes before it is written."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from models.sensitivity import dc_gain_sensitivity
from models.tf import TransferFunction


@dataclass(frozen=True)
class TfCheck:
    """A fitted term built exactly as the model file will hold it."""

    tf: TransferFunction
    dc_gain: float
    sensitivity: str
    poles: list[complex]


def build_checked_tf(num: Sequence[float], den: Sequence[float], name: str) -> TfCheck:
    """Build the term's `TransferFunction` from shortest round-trip reprs (the
    model file holds these strings, so the file reproduces the floats exactly).
    Raises `ModelError` when a pole is on or outside the unit circle."""
    tf = TransferFunction([repr(float(v)) for v in num], [repr(float(v)) for v in den],
                          name=name)
    return TfCheck(tf=tf, dc_gain=tf.dc_gain, sensitivity=dc_gain_sensitivity(tf).describe(),
                   poles=tf.poles)
