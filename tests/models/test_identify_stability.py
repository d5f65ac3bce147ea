"""How stable a choice is, the hedge when it is not, the textbook ARX
candidate, and rows masked from every loss (never cut from the simulation)."""

from __future__ import annotations

import numpy as np
import pytest

from models.identify.output_error import OeModel
from models.identify.segments import Segments
from models.identify.stability import block_errors, hedge, stability
from models.identify.structures import make_data, select_structure
from models.identify.textbook import pick_pair, textbook


def test_block_errors_cut_each_block() -> None:
    e = block_errors([np.array([1.0, 1.0, 2.0, 2.0]), np.array([3.0])], parts=2)
    assert e.tolist() == [2.0, 8.0, 9.0]


def test_a_clear_winner_is_stable_and_a_coin_toss_is_not() -> None:
    clear = stability([np.ones(8), np.full(8, 2.0)])
    assert clear.shares == (1.0, 0.0) and clear.block_wins == (1.0, 0.0)
    # the worked number of the module: three blocks of four to the first, but
    # every draw holding the fourth block goes to the second, 1 - (3/4)^4 = 68 %
    toss = stability([np.array([1.0, 1.0, 1.0, 5.0]), np.array([2.0, 2.0, 2.0, 1.0])])
    assert toss.block_wins == (0.75, 0.25)
    assert 0.63 < toss.shares[1] < 0.73 and sum(toss.shares) == pytest.approx(1.0)
    # the same errors give the same figure (a fixed seed)
    assert stability([np.array([1.0, 1.0, 1.0, 5.0]), np.array([2.0, 2.0, 2.0, 1.0])]) == toss
    # a diverged candidate loses every draw
    assert stability([np.full(4, np.inf), np.ones(4)]).shares == (0.0, 1.0)


def test_hedge_bets_only_on_a_stable_choice() -> None:
    assert hedge([0.7, 0.2, 0.1], 0) == [(0, 1.0)]
    mix = hedge([0.4, 0.35, 0.2, 0.05], 0)
    assert [i for i, _ in mix] == [0, 1, 2]  # shares to 0.8 cover, at most three
    assert sum(w for _, w in mix) == pytest.approx(1.0) and mix[0][1] > mix[1][1]
    # the chosen one need not be among the leaders: selected by stability
    assert hedge([0.1, 0.85, 0.05], 0) == [(1, 1.0)]


def _record(n: int = 1200) -> tuple[np.ndarray, list[np.ndarray]]:
    rng = np.random.default_rng(3)
    k = np.arange(n)
    heat = np.where((k // 150) % 2 == 0, 1.0, 0.0) * (1.0 + (k // 300) % 3)
    t1 = np.zeros(n)
    t2 = np.zeros(n)
    for i in range(1, n):
        t1[i] = 0.97 * t1[i - 1] + 0.03 * heat[i]
        t2[i] = 0.99 * t2[i - 1] + 0.01 * heat[i]
    y = 3.0 * t1 + 2.0 * t2 + 0.01 * rng.standard_normal(n)
    return y, [t1, t2, rng.standard_normal(n).cumsum() * 0.01]


def test_the_textbook_picks_the_sensors_that_explain_the_tool() -> None:
    y, us = _record()
    d = make_data(y, us, Segments.single(y.size), 1.0, 4, "forward")
    d.initial = False
    tb = textbook(d, us)
    assert tb is not None
    assert sorted(tb.inputs) == [0, 1]
    assert tb.validation_fit_pct > 90.0
    assert len(tb.residuals) == 4 and all(r.size for r in tb.residuals)


def test_a_vetoed_pair_gives_way_to_the_next_best_one() -> None:
    """`compd fit` may write only a textbook `compd check` passes: the pair is
    the best one the veto lets through, in order of inner hold-out MAE."""
    y, us = _record()
    d = make_data(y, us, Segments.single(y.size), 1.0, 4, "forward")
    d.initial = False
    free = pick_pair(d, us)
    assert free is not None and sorted(free) == [0, 1]
    asked: list[tuple[int, ...]] = []

    def veto(pair: tuple[int, ...], model: OeModel) -> str | None:
        asked.append(pair)
        assert len(model.nums) == 2  # the pair's estimate on every usable row
        return "terms that cancel" if sorted(pair) == [0, 1] else None

    second = pick_pair(d, us, veto)
    assert second is not None and sorted(second) != [0, 1]
    assert asked[0] == free and asked[-1] == second and len(asked) == 2
    tb = textbook(d, us, veto)
    assert tb is not None and tb.inputs == second
    # the second pair explains less of the tool than the vetoed one
    assert tb.validation_fit_pct < textbook(d, us).validation_fit_pct  # type: ignore[union-attr]
    # nothing passes: no textbook
    assert pick_pair(d, us, lambda pair, model: "no") is None
    assert textbook(d, us, lambda pair, model: "no") is None


def test_excluded_rows_are_never_fitted_nor_scored_but_simulated_through() -> None:
    y, us = _record()
    held = np.zeros(y.size, dtype=bool)
    held[500:700] = True
    d = make_data(y, us, Segments.single(y.size), 1.0, 4, "forward", ~held)
    assert d.usable is not None and not d.usable[held].any()
    for train, val in d.splits:
        assert not (train & held).any() and not (val & held).any() and val.any()
    # the folds are laid over the rows left: four held-out blocks of 200 rows
    assert [int(v.sum()) for _, v in d.splits] == [200] * 4
    # whatever the displacement does on the excluded rows, the choice is the same
    spoiled = y.copy()
    spoiled[held] = 1e3 * np.sin(np.arange(int(held.sum())))
    kw = dict(na_range=(2, 2), nb_range=(2, 2), structures=("arx",), usable=~held)
    a = select_structure(y, us[:2], **kw)  # type: ignore[arg-type]
    b = select_structure(spoiled, us[:2], **kw)  # type: ignore[arg-type]
    assert a.chosen.model == b.chosen.model
    assert a.chosen.validation_fit_pct == b.chosen.validation_fit_pct
    # and without the mask the spoiled rows change it
    c = select_structure(spoiled, us[:2], na_range=(2, 2), nb_range=(2, 2), structures=("arx",))
    assert c.chosen.model != a.chosen.model
