"""Coefficients exactly as printed.

A printed coefficient carries two facts: its value and its resolution (half a
unit in its last printed digit). Tables give both: ``16.0005`` is known to
±0.00005, ``10.01220`` to ±0.000005. Values are kept as `Decimal` until a
filter is built, so that exact cancellations (ε_amb's common factor
``1 - z⁻¹``) are found exactly rather than to within float rounding.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from decimal import Decimal, InvalidOperation

from models.errors import ModelError

#: a printed coefficient's decimal exponents stay within float64's range (1e308;
#: a 17-digit subnormal such as 2.7786728004711096e-295 has exponent -311)
MAX_EXPONENT = 308
MIN_EXPONENT = -400


@dataclass(frozen=True, slots=True)
class Printed:
    """One coefficient: its exact printed value and half a unit of its last digit."""

    value: Decimal
    half_unit: Decimal

    @property
    def structural(self) -> bool:
        """An exact zero is a structural absence, not a measured value."""
        return self.value == 0


def parse_coefficient(raw: float | int | str | Decimal, where: str) -> Printed:
    """Parse one coefficient given as a number or, to keep trailing zeros, a string.

    Floats are read through their shortest round-trip repr (``-0.99983``
    stays ``-0.99983``); strings keep every printed digit (``"10.01220"``).
    """
    if isinstance(raw, bool):
        raise ModelError(f"{where}: coefficient must be a number, got {raw!r}")
    if isinstance(raw, float) and not math.isfinite(raw):
        raise ModelError(f"{where}: coefficient is not finite ({raw!r})")
    text = repr(raw) if isinstance(raw, float) else str(raw).strip()
    try:
        value = Decimal(text)
    except (InvalidOperation, ValueError):
        raise ModelError(f"{where}: coefficient {raw!r} is not a number") from None
    if not value.is_finite():
        raise ModelError(f"{where}: coefficient is not finite ({raw!r})")
    exponent = value.as_tuple().exponent
    if not isinstance(exponent, int):  # pragma: no cover - finite checked above
        raise ModelError(f"{where}: coefficient {raw!r} is not finite")
    if not (MIN_EXPONENT <= exponent <= MAX_EXPONENT
            and (value == 0 or MIN_EXPONENT <= value.adjusted() <= MAX_EXPONENT)):
        raise ModelError(f"{where}: coefficient {raw!r} is outside the range of a float64 "
                         f"(decimal exponent beyond {MIN_EXPONENT} ... {MAX_EXPONENT})")
    half_unit = Decimal(5) * Decimal(10) ** (exponent - 1)
    return Printed(value=value, half_unit=half_unit)


def parse_coefficients(raw: Sequence[float | int | str | Decimal], where: str) -> list[Printed]:
    if isinstance(raw, str | bytes) or not isinstance(raw, Sequence):
        raise ModelError(f"{where}: expected a list of coefficients, got {raw!r}")
    return [parse_coefficient(c, f"{where}[{i}]") for i, c in enumerate(raw)]


def printed_text(p: Printed) -> str:
    """The coefficient as it was printed (trailing zeros kept)."""
    return str(p.value)
