"""A stateful discrete transfer function in the papers' difference-equation form.

docs/models.md §2, with numerator ``a`` and denominator ``b`` (the papers' naming,
the reverse of scipy's)::

    y(k) = ( a0·u(k) + … + an·u(k-n) - b1·y(k-1) - … - bm·y(k-m) ) / b0

At construction, once: coefficients are parsed exactly as printed, exact
common factors on the unit circle are cancelled (ε_amb's ``1 - z⁻¹``, which
would otherwise accumulate rounding at its z = 1 pole), and everything is
normalised by ``b0``. Stepping uses the direct form II transposed in float64,
the same arithmetic as ``scipy.signal.lfilter``.

Worked number (ε_SP3, a = [4.30702, -4.28923], b = [1, -0.9984]): a 1 K step
from rest gives y(0) = 4.30702 µm, y(100) = 5.31492 µm and settles at the DC
gain 0.01779 / 0.0016 = 11.11875 µm/K.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence
from decimal import Decimal, localcontext
from typing import Any

import numpy as np
import numpy.typing as npt

from models.coefficients import Printed, parse_coefficients
from models.errors import ModelError
from models.polynomials import (
    UNIT_ROOTS,
    cancel_unit_circle_factors,
    evaluate_at_unit_root,
    trim_trailing_zeros,
)

Coefficient = float | int | str | Decimal
FloatArray = npt.NDArray[np.float64]

#: a pole is "stable" only strictly inside the unit circle
STABILITY_MARGIN = 0.0


class TransferFunction:
    """One SISO discrete filter: ``step(u) -> y`` once per sample."""

    __slots__ = ("_den", "_n", "_num", "_z", "cancelled", "den_printed", "name",
                 "num_printed", "orig_den", "orig_num", "step")

    def __init__(self, a: Sequence[Coefficient], b: Sequence[Coefficient], name: str = "tf",
                 *, allow_unstable: bool = False) -> None:
        self.name = name
        num = parse_coefficients(a, f"{name}.a")
        den = parse_coefficients(b, f"{name}.b")
        if not den:
            raise ModelError(f"{name}.b: the denominator is empty")
        if not num:
            raise ModelError(f"{name}.a: the numerator is empty")
        if den[0].value == 0:
            raise ModelError(f"{name}.b[0]: b0 is zero; the difference equation divides by it")
        if all(c.value == 0 for c in num):
            raise ModelError(f"{name}.a: the numerator is all zeros (the term would do nothing)")
        # b0 is the normalisation convention: exact, not a measured digit
        den[0] = Printed(value=den[0].value, half_unit=Decimal(0))
        self.orig_num, self.orig_den = list(num), list(den)
        num, den = trim_trailing_zeros(num), trim_trailing_zeros(den)
        num, den, cancelled = cancel_unit_circle_factors(num, den)
        #: z values of pole/zero pairs cancelled at load (e.g. [1] for ε_amb)
        self.cancelled: list[int] = cancelled
        self.num_printed, self.den_printed = num, den
        n = max(len(num), len(den)) - 1
        self._n = n
        with localcontext() as ctx:
            ctx.prec = 60
            b0 = den[0].value
            num_f = [float(c.value / b0) for c in num] + [0.0] * (n + 1 - len(num))
            den_f = [float(c.value / b0) for c in den] + [0.0] * (n + 1 - len(den))
        den_f[0] = 1.0
        if not all(math.isfinite(c) for c in (*num_f, *den_f)):
            raise ModelError(f"{name}: a coefficient divided by b0 = {den[0].value} does not fit "
                             "in a float64 (overflow); rescale the model")
        self._num: tuple[float, ...] = tuple(num_f)
        self._den: tuple[float, ...] = tuple(den_f)
        self._z: list[float] = [0.0] * n
        if not allow_unstable and not self.is_stable:
            bad = [p for p in self.poles if abs(p) >= 1.0 - 1e-9]
            raise ModelError(
                f"{name}: unstable: pole(s) on or outside the unit circle at "
                + ", ".join(_fmt_complex(p) for p in bad)
                + " (a compensation filter must settle)")
        self.step = self._make_step()

    def __deepcopy__(self, memo: dict[int, Any]) -> TransferFunction:
        """A copy with a state of its own: `step` is a closure over the state list, so
        it is made again for the copy (a plain deep copy would keep stepping this one's)."""
        out = TransferFunction.__new__(TransferFunction)
        memo[id(self)] = out
        for name in self.__slots__:
            if name != "step":
                setattr(out, name, copy.deepcopy(getattr(self, name), memo))
        out.step = out._make_step()
        return out

    # -- stepping -----------------------------------------------------------------------------

    def _make_step(self) -> Any:
        """An order-specialised DF2T step bound to this object's state list."""
        z = self._z
        b = self._num
        a = self._den
        n = self._n
        if n == 0:
            b0 = b[0]

            def step0(u: float) -> float:
                return b0 * u
            return step0
        if n == 1:
            b0, b1 = b[0], b[1]
            a1 = a[1]

            def step1(u: float) -> float:
                y = b0 * u + z[0]
                z[0] = b1 * u - a1 * y
                return y
            return step1
        if n == 2:
            b0, b1, b2 = b[0], b[1], b[2]
            a1, a2 = a[1], a[2]

            def step2(u: float) -> float:
                y = b0 * u + z[0]
                z[0] = b1 * u + z[1] - a1 * y
                z[1] = b2 * u - a2 * y
                return y
            return step2
        if n == 3:
            b0, b1, b2, b3 = b[0], b[1], b[2], b[3]
            a1, a2, a3 = a[1], a[2], a[3]

            def step3(u: float) -> float:
                y = b0 * u + z[0]
                z[0] = b1 * u + z[1] - a1 * y
                z[1] = b2 * u + z[2] - a2 * y
                z[2] = b3 * u - a3 * y
                return y
            return step3

        last = n - 1

        def stepn(u: float) -> float:
            y = b[0] * u + z[0]
            for i in range(last):
                z[i] = b[i + 1] * u + z[i + 1] - a[i + 1] * y
            z[last] = b[n] * u - a[n] * y
            return y
        return stepn

    def simulate(self, u: Sequence[float] | FloatArray) -> FloatArray:
        """Step through a whole record; bit-for-bit the same numbers as `step`
        called once per sample (it is the same function). The state advances."""
        step = self.step
        return np.fromiter((step(float(x)) for x in u), dtype=np.float64, count=len(u))

    # -- state --------------------------------------------------------------------------------

    def reset(self) -> None:
        """Zero history."""
        for i in range(self._n):
            self._z[i] = 0.0

    def steady_state(self, u: float) -> float:
        """Set the delay lines so that a constant input `u` yields a constant
        output from now on; returns that output (dc_gain · u)."""
        if not math.isfinite(u):
            raise ModelError(f"{self.name}: steady state needs a finite input, got {u!r}")
        gain = self.dc_gain
        if not math.isfinite(gain):
            raise ModelError(f"{self.name}: no steady state: the filter integrates (DC gain ∞)")
        y = gain * u
        b, a, n = self._num, self._den, self._n
        acc = 0.0
        for i in range(n - 1, -1, -1):
            acc = b[i + 1] * u - a[i + 1] * y + (acc if i < n - 1 else 0.0)
            self._z[i] = acc
        return self._num[0] * u + (self._z[0] if n else 0.0)

    def export_state(self) -> dict[str, list[float]]:
        return {"z": list(self._z)}

    def import_state(self, state: dict[str, Any]) -> None:
        z = state.get("z") if isinstance(state, dict) else None
        if not isinstance(z, list) or len(z) != self._n:
            raise ModelError(f"{self.name}: state needs 'z' with {self._n} values, got {z!r}")
        values = [float(v) for v in z]
        if not all(math.isfinite(v) for v in values):
            raise ModelError(f"{self.name}: state holds a non-finite value: {values!r}")
        self._z[:] = values

    # -- analysis -----------------------------------------------------------------------------

    @property
    def order(self) -> int:
        return self._n

    @property
    def num(self) -> tuple[float, ...]:
        """Numerator after cancellation and normalisation (scipy's ``b``)."""
        return self._num

    @property
    def den(self) -> tuple[float, ...]:
        """Denominator after cancellation and normalisation (scipy's ``a``), den[0] = 1."""
        return self._den

    @property
    def poles(self) -> list[complex]:
        return _roots(self._den)

    @property
    def zeros(self) -> list[complex]:
        return _roots(self._num)

    @property
    def is_stable(self) -> bool:
        """All poles (after exact unit-circle cancellation) strictly inside the unit circle.

        A remaining pole exactly at z = ±1 is found from the printed digits, not
        from floating-point roots (which may land a hair inside the circle)."""
        if any(evaluate_at_unit_root(self.den_printed, r) == 0 for r in UNIT_ROOTS):
            return False
        return all(abs(p) < 1.0 - STABILITY_MARGIN for p in self.poles)

    @property
    def dc_gain(self) -> float:
        """sum(a) / sum(b) of the reduced form, computed exactly from the printed digits."""
        with localcontext() as ctx:
            ctx.prec = 60
            sa = sum((c.value for c in self.num_printed), Decimal(0))
            sb = sum((c.value for c in self.den_printed), Decimal(0))
            if sb == 0:
                return math.copysign(math.inf, float(sa)) if sa != 0 else math.nan
            return float(sa / sb)

    def __repr__(self) -> str:
        return f"TransferFunction(name={self.name!r}, num={self._num}, den={self._den})"


def _roots(coeffs: Sequence[float]) -> list[complex]:
    c = list(coeffs)
    while c and c[0] == 0.0:
        c.pop(0)
    if len(c) < 2:
        return []
    return [complex(r) for r in np.roots(np.asarray(c, dtype=np.float64))]


def _fmt_complex(p: complex) -> str:
    if abs(p.imag) < 1e-15:
        return f"{p.real:.6g}"
    return f"{p.real:.6g}{p.imag:+.6g}j (|p|={abs(p):.6g})"
