"""Grey-box ODE (docs/models.md §5) and MBOTV (§6)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from models.errors import ModelError
from models.greybox import GreyBox
from models.mbotv import Mbotv


def test_greybox_worked_number_and_euler_step() -> None:
    g = GreyBox([-1e-4, 2e-4, 0.0], period_s=10.0)
    y1 = g.step(5.0)
    assert y1 == pytest.approx(10.0 * 2e-4 * 5.0)  # y(1) = Ts·p2·u from rest
    for _ in range(200_000):
        y = g.step(5.0)
    assert y == pytest.approx(10.0, rel=1e-6)
    assert g.dc_gain == pytest.approx(2.0)


def test_greybox_switch_selects_the_standstill_parameters() -> None:
    g = GreyBox([-1e-3, 1e-3, 0.0, -2e-3, 0.0, 0.0], period_s=1.0)
    moving = g.step(4.0, 1.0)
    assert moving == pytest.approx(4e-3)
    still = g.step(4.0, 0.0)  # p5 = 0: only decays at p4
    assert still == pytest.approx(moving * (1 - 2e-3))


def test_greybox_steady_state_and_state_round_trip() -> None:
    g = GreyBox([-1e-3, 1e-3, 1.0], period_s=1.0)
    assert g.steady_state(3.0) == pytest.approx(4.0)
    assert g.step(3.0) == pytest.approx(4.0)
    h = GreyBox([-1e-3, 1e-3, 1.0], period_s=1.0)
    h.import_state(g.export_state())
    assert h.step(7.0) == g.step(7.0)


@pytest.mark.parametrize(("p", "message"), [
    ([1e-3, 1.0, 0.0], "unstable"),
    ([-3.0, 1.0, 0.0], "unstable"),  # Euler overshoots: |1 + Ts·p1| > 1
    ([-1e-3, 1.0], "expected 3 parameters"),
    ([-1e-3, math.nan, 0.0], "finite"),
])
def test_greybox_refuses_bad_parameters(p: list[float], message: str) -> None:
    with pytest.raises(ModelError, match=message):
        GreyBox(p, period_s=1.0)


def test_mbotv_settles_at_alpha_times_t_and_follows_the_equations() -> None:
    m = Mbotv(alpha=3.0, beta=50.0, k=0.99, gamma=0.5, period_s=1.0)
    for _ in range(5000):
        y = m.step(2.0)
    assert y == pytest.approx(6.0, rel=1e-9)
    # hand-computed first two samples from rest with T = 1, 2
    m2 = Mbotv(alpha=3.0, beta=50.0, k=0.9, gamma=0.5, period_s=1.0)
    z1 = 0.1 * 3.0
    zf1 = 0.5 * z1
    assert m2.step(1.0) == pytest.approx(zf1)
    zss2 = 3.0 * 2.0 + 50.0 * 1.0
    z2 = 0.9 * z1 + 0.1 * zss2
    assert m2.step(2.0) == pytest.approx(0.5 * zf1 + 0.5 * z2)


def test_mbotv_tau_and_state_round_trip() -> None:
    m = Mbotv.from_tau(alpha=2.0, beta=10.0, tau_s=600.0, gamma=0.8, period_s=10.0)
    assert m.k == pytest.approx(math.exp(-10.0 / 600.0))
    u = np.linspace(0, 5, 300)
    head = [m.step(float(x)) for x in u[:100]]
    n = Mbotv.from_tau(alpha=2.0, beta=10.0, tau_s=600.0, gamma=0.8, period_s=10.0)
    n.import_state(m.export_state())
    assert [n.step(float(x)) for x in u[100:]] == [m.step(float(x)) for x in u[100:]]
    assert len(head) == 100
    assert n.steady_state(1.5) == pytest.approx(3.0)


@pytest.mark.parametrize("kw", [{"k": 1.0}, {"gamma": -0.1}, {"alpha": math.inf}])
def test_mbotv_refuses_bad_parameters(kw: dict[str, float]) -> None:
    args = {"alpha": 1.0, "beta": 0.0, "k": 0.5, "gamma": 0.5, "period_s": 1.0} | kw
    with pytest.raises(ModelError):
        Mbotv(args["alpha"], args["beta"], args["k"], args["gamma"], args["period_s"])
