"""How well the printed digits determine a transfer function's DC gain.

Each printed coefficient is known to half a unit in its last printed digit
(``b0`` is the normalisation convention and exact; printed zeros are
structural). With A = sum(a) ± dA and B = sum(b) ± dB (reduced form):

- first-order sensitivity  s = dA/|B| + |A|·dB/B²  (µm/K)
- worst-case range of A/B over the box, unbounded when B's interval holds 0.

Worked number (ε_SP2): A = 0.003 ± 0.0001, B = 0.00017 ± 0.000005 gives
the range 16.57 … 18.79 µm/K; ε_SP1's B = 1e-4 ± 1.5e-4 straddles zero, so
its gain (-5 µm/K) is not determined by the table at all.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from decimal import Decimal, localcontext

from models.coefficients import Printed
from models.tf import TransferFunction


@dataclass(frozen=True, slots=True)
class DcGainSensitivity:
    dc_gain: float
    #: first-order change of the DC gain for half-unit moves of every printed digit, µm/K
    first_order: float
    #: worst-case DC gain over the same box; None where unbounded
    low: float | None
    high: float | None

    @property
    def bounded(self) -> bool:
        return self.low is not None and self.high is not None

    @property
    def well_determined(self) -> bool:
        """The printed digits pin the gain to within ±5 % (first order)."""
        return self.bounded and self.first_order <= 0.05 * abs(self.dc_gain)

    def describe(self, unit: str = "µm/K") -> str:
        """One line; `unit` is the DC gain's (µm/K for a temperature term)."""
        if not self.bounded:
            return (f"DC gain {self.dc_gain:.6g} {unit} is NOT determined by the printed "
                    "digits: the denominator sum can reach 0 within half a unit of its last "
                    f"digit (first-order sensitivity ±{self.first_order:.3g} {unit})")
        verdict = "well determined" if self.well_determined else "ill-determined"
        return (f"DC gain {self.dc_gain:.6g} {unit}, ±{self.first_order:.3g} {unit} to first "
                "order, "
                f"{self.low:.4g} … {self.high:.4g} within the printed digits ({verdict})")


def _sum_and_spread(coeffs: list[Printed]) -> tuple[Decimal, Decimal]:
    total = Decimal(0)
    spread = Decimal(0)
    for c in coeffs:
        total += c.value
        if not c.structural:
            spread += c.half_unit
    return total, spread


def dc_gain_sensitivity(tf: TransferFunction) -> DcGainSensitivity:
    with localcontext() as ctx:
        ctx.prec = 60
        A, dA = _sum_and_spread(tf.num_printed)
        B, dB = _sum_and_spread(tf.den_printed)
        if B == 0:
            return DcGainSensitivity(tf.dc_gain, math.inf, None, None)
        first = float(dA / abs(B) + abs(A) * dB / (B * B))
        if B - dB <= 0 <= B + dB:
            return DcGainSensitivity(tf.dc_gain, first, None, None)
        corners = [float((A + sa * dA) / (B + sb * dB)) for sa in (-1, 1) for sb in (-1, 1)]
        return DcGainSensitivity(tf.dc_gain, first, min(corners), max(corners))
