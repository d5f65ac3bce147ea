"""`compd fit` judges the model it writes on inner held-out blocks of every
kind cut from the calibration's speed (`compd.offline.fit_blocks`: interior
heat/cool cycles, cool-downs, the end), each left out of the calibration in
turn, the model run from the record's start: a model worse than no
compensation on one of them is replaced by the textbook ARX(2,3), and
nothing is written when that is worse too (`compd.offline.fit_judge`)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from compd.cli import main
from compd.offline import fit_judge
from compd.offline.fit_blocks import InnerBlock, inner_blocks
from compd.offline.fit_judge import AVERAGE, COMPD, NONE, TEXTBOOK, Member, judge, lean_score
from compd.sysexits import EX_DATAERR
from models.identify.output_error import OeModel
from models.identify.segments import Segments

#: the fl_thermal program: 1000 … 4000 rpm for 4 h each, each followed by 4 h at rest
SPEEDS = (1000.0, 0.0, 2000.0, 0.0, 3000.0, 0.0, 4000.0)
STRETCH = 240  # rows of 60 s: 4 h


def _record(path: Path, spoilt_stretch: int | None) -> None:
    """t1 heats with the speed (first order, 1 h); the displacement is 2 µm/K
    of t1, except in `spoilt_stretch`, where the tool feels nothing (back at
    its start) while t1 cools slowly: a cool-down the sensor mispredicts."""
    rng = np.random.default_rng(11)
    speed = np.repeat(SPEEDS, STRETCH)
    n = speed.size
    t1 = np.empty(n)
    t1[0] = 20.0
    for k in range(1, n):
        t1[k] = t1[k - 1] + (20.0 + speed[k] / 500.0 - t1[k - 1]) / 60.0
    y = 2.0 * (t1 - t1[0])
    if spoilt_stretch is not None:
        y[spoilt_stretch * STRETCH:(spoilt_stretch + 1) * STRETCH] = 0.0
    y = y + 0.03 * rng.standard_normal(n)
    path.write_text("time_s,spindle_rpm,t1_degC,dz_um\n" + "".join(
        f"{60 * i},{s:g},{a:.5f},{b:.5f}\n"
        for i, (s, a, b) in enumerate(zip(speed, t1, y, strict=True))))


def test_blocks_of_every_kind_are_cut_from_the_speed() -> None:
    speed = np.asarray(np.repeat(SPEEDS, STRETCH), dtype=np.float64)
    time_s = 60.0 * np.arange(speed.size, dtype=np.float64)
    blocks = inner_blocks(Segments.single(speed.size), None, speed, time_s)
    assert [(b.kind, b.name) for b in blocks] == [
        ("cycle", "cycle 8.0-16.0 h (2000 rpm)"), ("cycle", "cycle 16.0-24.0 h (3000 rpm)"),
        ("cool-down", "cool-down 4.0-8.0 h (from 1000 rpm)"),
        ("cool-down", "cool-down 12.0-16.0 h (from 2000 rpm)"),
        ("cool-down", "cool-down 20.0-24.0 h (from 3000 rpm)"),
        ("end", "end 24.0-28.0 h (4000 rpm)")]
    assert blocks[2].rows.sum() == STRETCH and blocks[0].rows.sum() == 2 * STRETCH
    # rows held out of the calibration are never scored: that cycle's blocks go
    held = np.zeros(speed.size, dtype=bool)
    held[2 * STRETCH:4 * STRETCH] = True
    names = [b.name for b in inner_blocks(Segments.single(speed.size), ~held, speed, time_s)]
    assert "cycle 8.0-16.0 h (2000 rpm)" not in names
    assert "cool-down 12.0-16.0 h (from 2000 rpm)" not in names
    # without a speed: equal parts, the interior ones and the end
    plain = inner_blocks(Segments.single(1000), None)
    assert [b.kind for b in plain] == ["interior"] * 3 + ["end"]


def test_a_model_worse_than_none_on_an_inner_cool_down_is_not_written(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    data, out = tmp_path / "rec.csv", tmp_path / "m.toml"
    _record(data, spoilt_stretch=3)  # the cool-down from 2000 rpm
    argv = ["fit", str(data), "--column", "dz_um", "--term", "t1_degC", "-o", str(out),
            "--no-fallbacks"]
    assert main(argv) == EX_DATAERR
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert "no model is safer than no compensation" in err and "nothing written" in err
    assert "worse than no compensation on the inner block cool-down 12.0-16.0 h" in err
    assert not out.exists()
    # --force writes compd's choice, and says the verdict
    assert main([*argv, "--force"]) == 0
    captured = capsys.readouterr()
    assert "compd's choice written all the same (--force)" in captured.err
    assert "judged on 6 inner held-out blocks" in captured.out
    assert "written: nothing (" in captured.out and out.exists()


def test_a_good_model_is_written_and_says_the_blocks_that_judged_it(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    data, out = tmp_path / "rec.csv", tmp_path / "m.toml"
    _record(data, spoilt_stretch=None)
    assert main(["fit", str(data), "--column", "dz_um", "--term", "t1_degC", "-o", str(out),
                 "--no-fallbacks", "--json"]) == 0
    verdict = json.loads(capsys.readouterr().out)["terms"][0]["selection"]["judge"]
    assert len(verdict["blocks"]) == 6
    # the model predicts every inner block far better than no compensation, and
    # so does the textbook (ARX(2,3) on t1): both at the noise, 0.02-0.03 µm.
    # Not twice as good as the textbook, compd's choice gives way to the average
    # of the two (`fit_judge.LEAN_RATIO`), as good on every block
    assert verdict["chosen"] == AVERAGE
    for k, none in enumerate(verdict["mae_um"][NONE]):
        mine, tb, avg = (verdict["mae_um"][n][k] for n in (COMPD, TEXTBOOK, AVERAGE))
        assert max(mine, tb, avg) < 0.03 < 0.2 * none
        assert avg <= max(mine, tb)


def _verdict(monkeypatch: pytest.MonkeyPatch, compd_err: list[float],
             textbook_err: list[float], forced: bool = False, tie: float = 1.05,
             worse_ratio: float = 1.1, last: str = "interior",
             lean_ratio: float = math.inf) -> fit_judge.Verdict:
    """The verdict on three blocks of 10 rows whose displacement is 1 µm (no
    compensation's error 1 µm), each candidate's prediction off by its error
    (the average's by the mean of the two errors); the third block of kind
    `last`; `lean_ratio`: `fit_judge.LEAN_RATIO` (inf: compd's choice never
    gives way to the average with the textbook)."""
    n = 40
    y = np.ones(n)
    y[0] = 0.0
    rows = []
    for k in range(3):
        r = np.zeros(n, dtype=bool)
        r[10 * (k + 1):10 * (k + 2)] = True
        rows.append(InnerBlock(f"block {k}", last if k == 2 else "interior", r))

    def refit(y_: object, seg: object, radius: object, usable: object, member: Member,
              train: np.ndarray) -> np.ndarray:
        k = next(i for i, b in enumerate(rows) if not train[b.rows].any())
        err = (textbook_err if member.structure == "textbook" else compd_err)[k]
        return y - err

    monkeypatch.setattr(fit_judge, "refit", refit)
    monkeypatch.setattr(fit_judge, "TIE", tie)
    monkeypatch.setattr(fit_judge, "WORSE_RATIO", worse_ratio)
    monkeypatch.setattr(fit_judge, "LEAN_RATIO", lean_ratio)
    model = OeModel(nums=((1.0,),), dens=((1.0,),), groups=((0,),))
    verdict = judge(y, Segments.single(n), 1.0, None, rows,
                    [(Member("arx", (np.zeros(n),), model), 1.0)],
                    Member("textbook", (np.zeros(n),), model), forced=forced)
    assert verdict is not None
    return verdict


def test_the_verdict_falls_back_to_the_textbook_then_to_nothing(
        monkeypatch: pytest.MonkeyPatch) -> None:
    # the smallest worst ratio (1.33 against 4.5), but 1.2x no compensation on the
    # third block: the textbook takes its place
    v = _verdict(monkeypatch, [0.2, 0.2, 1.2], [0.9, 0.9, 0.9])
    assert v.worst[COMPD] < v.worst[TEXTBOOK] and v.chosen == TEXTBOOK
    assert v.reasons == ["compd's choice is worse than no compensation on the inner block "
                         "block 2 (MAE 1.2 µm against 1 µm uncompensated)"]
    # both worse than none somewhere: nothing
    v = _verdict(monkeypatch, [0.2, 0.2, 1.2], [0.9, 1.3, 0.9])
    assert v.chosen == NONE and len(v.reasons) == 2
    # the default: compd's choice unless a candidate is 1.5x no compensation
    v = _verdict(monkeypatch, [0.25, 0.9, 0.3], [0.3, 0.3, 0.3], tie=math.inf, worse_ratio=1.5)
    assert v.chosen == COMPD and v.reasons == []
    v = _verdict(monkeypatch, [0.2, 0.2, 1.6], [0.9, 0.9, 0.9], tie=math.inf, worse_ratio=1.5)
    assert v.chosen == TEXTBOOK
    # with a tie set, never much worse beats best on one block: the smaller worst ratio wins
    v = _verdict(monkeypatch, [0.25, 0.9, 0.3], [0.3, 0.3, 0.3])
    assert v.chosen == TEXTBOOK and v.worst[COMPD] == pytest.approx(3.0)
    # close worst ratios: compd's choice
    assert _verdict(monkeypatch, [0.1, 0.31, 0.1], [0.3, 0.3, 0.3]).chosen == COMPD
    # a structure forced by the user is written or refused, never replaced
    assert _verdict(monkeypatch, [0.25, 0.9, 0.3], [0.3, 0.3, 0.3], forced=True).chosen == COMPD
    assert _verdict(monkeypatch, [0.1, 0.1, 1.5], [0.3, 0.3, 0.4], forced=True).chosen == NONE


def test_the_end_judges_only_the_textbook_in_compds_choices_place(
        monkeypatch: pytest.MonkeyPatch) -> None:
    # 1.6x no compensation on the end alone: compd's choice, a later stretch at a
    # faster speed being what it was chosen on; on an interior block it would go
    v = _verdict(monkeypatch, [0.2, 0.2, 1.6], [0.9, 0.9, 0.9], tie=math.inf,
                 worse_ratio=1.5, last="end")
    assert v.chosen == COMPD and v.reasons == [] and v.kinds == ["interior"] * 2 + ["end"]
    assert v.as_dict()["kinds"] == v.kinds
    assert _verdict(monkeypatch, [0.2, 0.2, 1.6], [0.9, 0.9, 0.9], tie=math.inf,
                    worse_ratio=1.5).chosen == TEXTBOOK
    # refused on an interior block, its textbook is judged on the end too
    v = _verdict(monkeypatch, [1.6, 0.2, 0.2], [0.9, 0.9, 1.6], tie=math.inf,
                 worse_ratio=1.5, last="end")
    assert v.chosen == NONE
    assert v.reasons[-1] == ("textbook is worse than no compensation on the inner block "
                             "block 2 (MAE 1.6 µm against 1 µm uncompensated)")
    # a structure forced by the user: the same, written or refused on the interior ones
    assert _verdict(monkeypatch, [0.2, 0.2, 1.6], [0.9, 0.9, 0.9], forced=True,
                    tie=math.inf, worse_ratio=1.5, last="end").chosen == COMPD


def test_a_choice_the_textbook_beats_on_the_inner_blocks_is_averaged_with_it(
        monkeypatch: pytest.MonkeyPatch) -> None:
    # the textbook better on two blocks of three (0.2 against 0.6 µm), compd's choice
    # on one (0.1 against 0.3): its MAE is (3 · 3 · 1/3)^(1/3) = 1.44x the textbook's
    v = _verdict(monkeypatch, [0.6, 0.6, 0.1], [0.2, 0.2, 0.3], tie=math.inf,
                 worse_ratio=1.5, lean_ratio=1.0)
    assert v.chosen == AVERAGE
    # the average's error is the mean of the two: 0.4, 0.4, 0.2 µm
    assert v.mae[AVERAGE] == pytest.approx([0.4, 0.4, 0.2])
    assert v.reasons == ["compd's choice does not beat the textbook on the inner blocks by "
                         "enough (its MAE is 1.44x the textbook's, geometric mean over 3 "
                         "blocks; alone at most 1.00x)"]
    assert lean_score(v.mae, v.floor) == pytest.approx(3.0 ** (1.0 / 3.0))
    # compd's choice better on two blocks of three: kept (0.69x the textbook's)
    v = _verdict(monkeypatch, [0.1, 0.1, 0.6], [0.3, 0.3, 0.2], tie=math.inf,
                 worse_ratio=1.5, lean_ratio=1.0)
    assert v.chosen == COMPD and v.reasons == []
    assert lean_score(v.mae, v.floor) == pytest.approx((1.0 / 3.0) ** (1.0 / 3.0))
    # a looser lean keeps the first choice too; inf never leans
    assert _verdict(monkeypatch, [0.6, 0.6, 0.1], [0.2, 0.2, 0.3], tie=math.inf,
                    worse_ratio=1.5, lean_ratio=1.5).chosen == COMPD
    # the average must itself pass the safety rule on every block, the end included:
    # 1.9 µm off on the end (no compensation 1 µm), the choice stays
    v = _verdict(monkeypatch, [0.6, 0.6, 1.6], [0.2, 0.2, 2.2], tie=math.inf,
                 worse_ratio=1.5, lean_ratio=1.0, last="end")
    assert v.mae[AVERAGE][2] == pytest.approx(1.9) and v.chosen == COMPD
    # a structure forced by the user is never averaged
    assert _verdict(monkeypatch, [0.6, 0.6, 0.1], [0.2, 0.2, 0.3], forced=True,
                    tie=math.inf, worse_ratio=1.5, lean_ratio=1.0).chosen == COMPD


def _fit_judged(monkeypatch: pytest.MonkeyPatch, tmp_path: Path, textbook_better: bool,
                textbook_folds: float = 1.0) -> tuple[dict[str, Any], str, str]:
    """`compd fit` on a two-sensor record whose inner blocks the textbook (or compd's
    choice) predicts exactly and the other 0.5 µm off: (the model file's terms, the
    fit's stdout, its stderr). `textbook_folds` scales the textbook's residue on the
    folds' held-out rows."""
    import dataclasses
    import tomllib

    from compd.offline import fit_hedge

    if textbook_folds != 1.0:
        real_textbook = fit_hedge.textbook  # type: ignore[attr-defined]

        def textbook(*a: Any, **kw: Any) -> Any:
            tb = real_textbook(*a, **kw)
            return None if tb is None else dataclasses.replace(
                tb, residuals=tuple(textbook_folds * r for r in tb.residuals))

        monkeypatch.setattr(fit_hedge, "textbook", textbook)
    data = tmp_path / "rec.csv"
    out = tmp_path / f"m{int(textbook_better)}{textbook_folds:g}.toml"
    _record(data, spoilt_stretch=None)
    rows = data.read_text().splitlines()
    rng = np.random.default_rng(5)
    # a second sensor: t1 lagging by 2 h, with its own noise
    t1 = np.array([float(r.split(",")[2]) for r in rows[1:]])
    t2 = np.empty_like(t1)
    t2[0] = t1[0]
    for k in range(1, t1.size):
        t2[k] = t2[k - 1] + (t1[k] - t2[k - 1]) / 120.0
    t2 += 0.01 * rng.standard_normal(t2.size)
    data.write_text("time_s,spindle_rpm,t1_degC,t2_degC,dz_um\n" + "".join(
        f"{r.rsplit(',', 1)[0]},{b:.5f},{r.rsplit(',', 1)[1]}\n"
        for r, b in zip(rows[1:], t2, strict=True)))
    real_refit = fit_judge.refit

    def refit(y: np.ndarray, seg: Segments, radius: float, usable: object,
              member: Member, train: np.ndarray) -> np.ndarray | None:
        sim = real_refit(y, seg, radius, usable, member, train)  # type: ignore[arg-type]
        if sim is None:
            return None
        exact = (member.structure == "textbook") == textbook_better
        return np.asarray(y if exact else y - 0.5)

    monkeypatch.setattr(fit_judge, "refit", refit)
    monkeypatch.setattr(fit_judge, "LEAN_RATIO", 1.0)
    monkeypatch.setattr(fit_judge, "LEAN_TO", AVERAGE)
    argv = ["fit", str(data), "--column", "dz_um", "--term", "t1_degC", "--term", "t2_degC",
            "-o", str(out), "--no-fallbacks"]
    import contextlib
    import io

    o, e = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(o), contextlib.redirect_stderr(e):
        assert main(argv) == 0
    return tomllib.loads(out.read_text()), o.getvalue(), e.getvalue()


def test_fit_writes_the_average_where_the_textbook_wins_the_inner_blocks(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    kept, out_kept, err_kept = _fit_judged(monkeypatch, tmp_path, textbook_better=False)
    assert "written: compd's choice" in out_kept and "fell back" not in err_kept
    avg, out_avg, err_avg = _fit_judged(monkeypatch, tmp_path, textbook_better=True)
    assert "compd fit: fell back to average of compd's choice" in err_avg
    assert "does not beat the textbook on the inner blocks by enough (its MAE is" in err_avg
    assert "written: average of compd's choice" in out_avg
    # the average's terms: compd's choice's at half weight beside the textbook's
    mine = {t["name"]: t for t in kept["terms"]}
    both = {t["name"]: t for t in avg["terms"]}
    assert set(mine) < set(both) and len(both) == len(mine) + 2
    for name, t in mine.items():  # numerator `a`, denominator `b`
        half = [float(v) for v in both[name]["a"]]
        assert half == pytest.approx([0.5 * float(v) for v in t["a"]], rel=1e-12)
        assert both[name]["b"] == t["b"]
    # the textbook's: ARX(2,3), three numerator coefficients over a second order
    for name in set(both) - set(mine):
        assert len(both[name]["a"]) == 3 and len(both[name]["b"]) == 3


def test_an_average_worse_than_none_on_the_folds_leaves_the_choice(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    # the textbook's residue on the folds' held-out rows 1000 times over: the average
    # would be refused as worse than no compensation there, where the choice passed
    kept, _, _ = _fit_judged(monkeypatch, tmp_path, textbook_better=False)
    alone, out, err = _fit_judged(monkeypatch, tmp_path, textbook_better=True,
                                  textbook_folds=1000.0)
    assert "not averaged, the average's error on the rows the folds held out (RMS" in out
    assert "written: compd's choice (" in out and "fell back" not in err
    assert alone["terms"] == kept["terms"]
