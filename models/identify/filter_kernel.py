"""`lfilter`'s own kernel for the identification's filters, loaded without
the rest of `scipy.signal`.

Every filter of a fit is ``lfilter(b, a, x)`` on float64 1-D arrays, and
`lfilter` hands such a call to one C function (``_linear_filter`` of
scipy's ``_sigtools`` extension) after checks and conversions that change
no number. Importing `scipy.signal` to reach it loads scipy.stats,
scipy.interpolate, scipy.optimize and scipy.spatial too: about a second of
CPU at every `compd fit`, a tenth of a day-long fit at 1 s, for functions
the fit never calls. So the extension is loaded here from its file alone
(it needs only numpy); where scipy's layout has no such file, or it does not
load, `_linear_filter` comes from `scipy.signal` as before, and where that
fails too, `lfilter` itself runs (the same numbers, slower).

`lfilter_rest` and `filter_zi` are ``lfilter(b, a, x)`` and ``lfilter(b, a,
x, zi=zi)`` by the very calls `lfilter` makes for them (scipy 1.17): the
kernel for a recursive filter, the full convolution for a FIR one.
"""

from __future__ import annotations

import glob
import importlib.machinery
import importlib.util
import os
from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

#: the extension module's name within scipy
_NAME = "scipy.signal._sigtools"


def _load_kernel() -> Callable[..., Any] | None:
    """``_linear_filter`` from scipy's ``_sigtools`` extension file, loaded on its
    own; else from `scipy.signal`; None when neither has it."""
    try:
        import scipy

        for path in sorted(glob.glob(os.path.join(scipy.__path__[0], "signal", "_sigtools*"))):
            if not path.endswith(tuple(importlib.machinery.EXTENSION_SUFFIXES)):
                continue
            loader = importlib.machinery.ExtensionFileLoader(_NAME, path)
            spec = importlib.util.spec_from_file_location(_NAME, path, loader=loader)
            if spec is None:
                continue
            module = importlib.util.module_from_spec(spec)
            loader.exec_module(module)
            kernel: Callable[..., Any] = module._linear_filter
            return kernel
    except (ImportError, AttributeError, OSError):
        pass
    try:
        from scipy.signal._sigtools import _linear_filter
    except ImportError:  # pragma: no cover - another scipy layout: lfilter itself
        return None
    found: Callable[..., Any] = _linear_filter
    return found


def _answers_as_lfilter(kernel: Callable[..., Any] | None) -> Callable[..., Any] | None:
    """`kernel` when it filters a known case as `lfilter` does (y[n] = x[n] + y[n-1]/2,
    from rest and from a state); None when it raises or differs, as a scipy whose
    private kernel changed its calling convention would: then `lfilter` runs."""
    if kernel is None:
        return None
    b, a = np.array([1.0]), np.array([1.0, -0.5])
    x = np.array([1.0, 0.0, 0.0])
    try:
        rest = np.asarray(kernel(b, a, x, -1), dtype=np.float64)
        out, zf = kernel(b, a, x, -1, np.array([2.0]))
    except Exception:  # any failure of a private function means: do not use it
        return None
    if (rest.tolist() == [1.0, 0.5, 0.25] and np.asarray(out).tolist() == [3.0, 1.5, 0.75]
            and np.asarray(zf).tolist() == [0.375]):
        return kernel
    return None


_linear_filter = _answers_as_lfilter(_load_kernel())


def lfilter_rest(b: FloatArray, a: FloatArray, x: FloatArray) -> FloatArray:
    """``lfilter(b, a, x)`` (from rest) for float64 1-D `b`, `a` (a[0] = 1) and `x`."""
    if _linear_filter is None or a[0] != 1.0:
        from scipy.signal import lfilter

        return np.asarray(lfilter(b, a, x), dtype=np.float64)
    if a.size == 1:  # lfilter's FIR path: the full convolution's head
        return np.convolve(b, x)[:x.size]
    out: FloatArray = _linear_filter(b, a, x, -1)
    return out


def filter_zi(b: FloatArray, a: FloatArray, x: FloatArray, zi: FloatArray
              ) -> tuple[FloatArray, FloatArray]:
    """``lfilter(b, a, x, zi=zi)`` for float64 1-D arrays with a[0] = 1 and zi
    of max(len(a), len(b)) - 1 values, by the very arithmetic `lfilter` runs
    (its recursive kernel; a FIR filter its convolution) without its checks
    and conversions of every argument, which cost as much as the filtering on
    a block of a few thousand rows."""
    if _linear_filter is None or a[0] != 1.0 or zi.size != max(a.size, b.size) - 1:
        from scipy.signal import lfilter

        out, zf = lfilter(b, a, x, zi=zi)
        return np.asarray(out, dtype=np.float64), np.asarray(zf, dtype=np.float64)
    if a.size == 1:  # lfilter's FIR path: the full convolution, zi added to its head
        full = np.convolve(b, x)
        full[:zi.size] += zi
        return full[:x.size], full[x.size:]
    out, zf = _linear_filter(b, a, x, -1, zi)
    return out, zf
