"""Exact polynomial helpers in z⁻¹ on printed (Decimal) coefficients.

A polynomial ``p0 + p1 q + … + pn qⁿ`` in ``q = z⁻¹`` has a root at z = 1
when its coefficients sum to zero, and at z = -1 when their alternating sum
is zero. Deflation by ``(1 ∓ q)`` keeps the printed resolution: each quotient
coefficient is a signed partial sum, so its half-unit is the sum of the
half-units it adds up (conservative).
"""

from __future__ import annotations

from decimal import Decimal

from models.coefficients import Printed

#: unit-circle points whose common factor is cancelled at load: z = 1 and z = -1
UNIT_ROOTS: tuple[int, ...] = (1, -1)


def evaluate_at_unit_root(p: list[Printed], root: int) -> Decimal:
    """P(q) at q = 1/root exactly (sum, or alternating sum)."""
    total = Decimal(0)
    for k, c in enumerate(p):
        total += c.value if root == 1 or k % 2 == 0 else -c.value
    return total


def deflate(p: list[Printed], root: int) -> list[Printed]:
    """Divide by ``(1 - q/root)``; the caller has checked the remainder is zero."""
    out: list[Printed] = []
    value = Decimal(0)
    half = Decimal(0)
    for c in p[:-1]:
        value = c.value + (value if root == 1 else -value)
        half = (half + c.half_unit) if not c.structural else half
        out.append(Printed(value=value, half_unit=half))
    return out


def trim_trailing_zeros(p: list[Printed]) -> list[Printed]:
    out = list(p)
    while len(out) > 1 and out[-1].structural:
        out.pop()
    return out


def cancel_unit_circle_factors(
        num: list[Printed], den: list[Printed]) -> tuple[list[Printed], list[Printed], list[int]]:
    """Remove every common factor ``(1 - z⁻¹)`` / ``(1 + z⁻¹)`` exactly.

    Returns the reduced numerator and denominator and the cancelled roots
    (z values), so that a loader can report them rather than hide them.
    """
    cancelled: list[int] = []
    changed = True
    while changed:
        changed = False
        for root in UNIT_ROOTS:
            if (len(num) > 1 and len(den) > 1
                    and evaluate_at_unit_root(num, root) == 0
                    and evaluate_at_unit_root(den, root) == 0):
                num, den = deflate(num, root), deflate(den, root)
                cancelled.append(root)
                changed = True
    return num, den, cancelled
