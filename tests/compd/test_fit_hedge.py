"""The hedge `compd fit` writes when its choice is not stable: a weighted
sum of the leading candidates, which is again a model of difference-equation
terms the daemon steps."""

from __future__ import annotations

import numpy as np

from compd.offline.fit_hedge import _merge
from compd.offline.fit_select import FitTerm


def test_terms_on_one_input_and_denominator_merge_and_names_stay_unique() -> None:
    u = np.arange(5.0)
    den = (1.0, -0.5)
    terms = [FitTerm("t1", {"t1": 1.0}, u, (0.2, 0.1), den, True),
             FitTerm("t1", {"t1": 1.0}, u, (0.3,), den, True),
             FitTerm("t1", {"t1": 1.0}, u, (0.4, 0.0), (1.0, -0.9), True),
             FitTerm("t2", {"t2": 1.0}, u, (0.1,), den, True)]
    out = _merge(terms)
    assert [t.name for t in out] == ["t1", "t1.2", "t2"]
    assert out[0].num == (0.5, 0.1) and out[0].den == den  # summed numerators
    assert out[1].den == (1.0, -0.9)
