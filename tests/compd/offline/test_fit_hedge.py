"""The hedge `compd fit` writes when its choice is not stable: a weighted
sum of the leading candidates, which is again a model of difference-equation
terms the daemon steps."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest

from compd.offline.fit_hedge import _merge
from compd.offline.fit_terms import FitTerm


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


def test_an_average_says_the_orders_of_its_terms() -> None:
    """After an average of a static and a second-order member, the fallback
    line says the orders the written terms have, not the static stage's 0."""
    from compd.offline.fit_checks import CheckVeto, fallback_line
    from compd.offline.fit_hedge import term_orders

    u = np.arange(5.0)
    terms = [FitTerm("t1", {"t1": 1.0}, u, (0.2,), (1.0,), True),
             FitTerm("t1.2", {"t1": 1.0}, u, (0.2, 0.1, 0.0), (1.0, -0.5, 0.1), True)]
    assert term_orders(terms) == {"denominator_order": "0-2", "numerator_length": "1-3"}
    assert term_orders(terms[1:]) == {"denominator_order": 2, "numerator_length": 3}
    veto = CheckVeto([("t1", {"t1": 1.0})], [True], [1.0], 1.0, 60.0)
    veto.vetoed.append("a negative real pole")
    summary = {"structure": "average of static on t1 ×0.5, arx on t1 ×0.5",
               "orders": term_orders(terms), "candidates": [],
               "notes": ["failed: denominator orders 2-4: compd check would warn: …"]}
    line = fallback_line(summary, veto)
    assert line is not None and "(denominator order 0-2, numerator length 1-3)" in line


def _record(path: Path, noise: float, seed: int) -> npt.NDArray[np.float64]:
    """Two first-order sensors the tool follows, a third that wanders; `noise` µm on
    the displacement."""
    rng = np.random.default_rng(seed)
    n = 900
    k = np.arange(n)
    heat = np.where((k // 120) % 2 == 0, 1.0, 0.0) * (1.0 + (k // 240) % 3)
    t = np.zeros((3, n))
    for i in range(1, n):
        t[0, i] = 0.97 * t[0, i - 1] + 0.03 * heat[i]
        t[1, i] = 0.99 * t[1, i - 1] + 0.01 * heat[i]
    t[2] = rng.standard_normal(n).cumsum() * 0.01
    y: npt.NDArray[np.float64] = 3.0 * t[0] + 2.0 * t[1] + noise * rng.standard_normal(n)
    path.write_text("time_s,t1_degC,t2_degC,t3_degC,dz_um\n" + "".join(
        f"{60 * i},{20 + t[0, i]:.5f},{20 + t[1, i]:.5f},{20 + t[2, i]:.5f},{y[i]:.5f}\n"
        for i in range(n)))
    return y


def _fit_searched(data: Path, out: Path) -> None:
    from compd.cli import main

    assert main(["fit", str(data), "--column", "dz_um", "--candidates", "t*_degC",
                 "--max-terms", "2", "--orders", "2-2", "-o", str(out), "--json",
                 "--no-fallbacks"]) == 0


def test_searched_inputs_share_the_model_with_the_textbook(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """With a textbook share (off by default: the benchmark judges it) the
    model of searched inputs is that share of the textbook ARX(2,3) on its
    pair, said in the provenance; the written model steps as that sum."""
    from compd.infiles import load_model
    from compd.offline import fit_hedge
    from compd.offline.model_replay import replay_model
    from compd.offline.records import read_record

    assert fit_hedge.TEXTBOOK_SHARE == 0.0
    monkeypatch.setattr(fit_hedge, "TEXTBOOK_SHARE", 0.5)
    data, out = tmp_path / "rec.csv", tmp_path / "m.toml"
    y = _record(data, 0.1, 8)
    _fit_searched(data, out)
    model = load_model(out)
    text = model.provenance["choice_stability_text"]
    assert any("inputs searched: the textbook takes 50 %" in line for line in text)
    assert any("0.50 × textbook ARX(2,3) on" in line for line in text)
    # the written model still explains the tool: a sum of terms the daemon steps
    sim = replay_model(model, read_record(str(data)))
    assert float(np.sqrt(np.mean((y - sim) ** 2))) < 0.2
    capsys.readouterr()


def test_a_textbook_check_warns_about_takes_no_share(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """The textbook is a candidate like the others: when `compd check` would warn
    about it (here a negative real pole of its ARX(2,3) on t2 + t3) it takes no
    share of the model, and the provenance says why."""
    from compd.infiles import load_model
    from compd.offline import fit_hedge

    monkeypatch.setattr(fit_hedge, "TEXTBOOK_SHARE", 0.5)
    data, out = tmp_path / "rec.csv", tmp_path / "m.toml"
    _record(data, 0.02, 7)
    _fit_searched(data, out)
    model = load_model(out)
    text = model.provenance["choice_stability_text"]
    assert any("left out, compd check would warn: textbook ARX(2,3)" in line
               and "negative real pole" in line for line in text)
    assert not any("textbook takes" in line for line in text)
    assert all("t3_degC" not in t.inputs for t in model.terms)
    capsys.readouterr()


def test_an_average_check_warns_about_is_not_written(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """An average is a model of its own: when `compd check` would warn about it,
    the choice is written alone (its terms only), and that is said."""
    from compd.infiles import load_model
    from compd.offline import fit_hedge
    from compd.offline.fit_checks import CheckVeto

    monkeypatch.setattr(fit_hedge, "TEXTBOOK_SHARE", 0.5)
    real = CheckVeto.terms

    def no_averages(self: CheckVeto, fitted: list[FitTerm]) -> str | None:
        return "test: an average" if len(fitted) > 2 else real(self, fitted)

    monkeypatch.setattr(CheckVeto, "terms", no_averages)
    # the hedge's own choice, without the inner blocks' verdict after it (which
    # writes the textbook here: tests/compd/offline/test_fit_inner_blocks.py)
    from compd.offline import fit_judge

    monkeypatch.setattr(fit_judge, "judge", lambda *a, **k: None)
    data, out = tmp_path / "rec.csv", tmp_path / "m.toml"
    _record(data, 0.1, 8)
    _fit_searched(data, out)
    model = load_model(out)
    text = model.provenance["choice_stability_text"]
    assert any("not averaged, the choice written alone: compd check would warn about the "
               "average: test: an average" in line for line in text)
    assert not any("averages" in line for line in text)
    assert not str(model.provenance["structure"]).startswith("average")
    # the terms written are the choice's, on its inputs only
    chosen = text[0].split("stability of the choice: ", 1)[1].split(" wins ", 1)[0]
    inputs = chosen.rsplit(" on ", 1)[1].split(" + ")
    assert sorted(t.name for t in model.terms) == sorted(inputs)
    capsys.readouterr()


def test_an_averaged_model_has_a_fallback_for_every_channel_it_reads(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Members of an average may read channels the search did not choose (here the
    choice is t2 alone, the average reads t1 too): each such channel gets its
    fallback, and no fallback's own average reads a channel the main model does not
    (the model file would be refused) or the one it stands in for."""
    from compd.cli import main
    from compd.infiles import load_model

    data, out = tmp_path / "rec.csv", tmp_path / "m.toml"
    _record(data, 0.1, 8)
    assert main(["fit", str(data), "--column", "dz_um", "--candidates", "t*_degC",
                 "--max-terms", "2", "--orders", "2-2", "-o", str(out), "--json"]) == 0
    model = load_model(out)
    reads = {ch for t in model.terms for ch in t.inputs}
    assert str(model.provenance["structure"]).startswith("average") and reads == {"t1_degC",
                                                                                 "t2_degC"}
    # t1 was not chosen, yet the model reads it: its loss has a fallback (on t2)
    assert set(model.fallbacks) == {"t1_degC"}
    for lost, fb in model.fallbacks.items():
        fb_reads = {ch for t in fb.terms for ch in t.inputs}
        assert fb_reads and lost not in fb_reads and fb_reads <= reads
    # the chosen input alone leaves nothing to fit without it: said, none written
    assert "no fallback without t2_degC: no term is left without it" in capsys.readouterr().err


def test_no_fallback_reads_a_chosen_input_the_average_left_out(tmp_path: Path) -> None:
    """An average may leave a chosen input out (another screen's winner alone won the
    draws): the model reads t1 only, though t1 and t2 were chosen. Its fallbacks are
    fitted on what it reads, never on t2 (the model file would be refused)."""
    from compd.offline.fit_fallback import fit_fallbacks
    from compd.offline.fit_request import FitRequest, FitRun
    from compd.offline.records import read_record

    data = tmp_path / "rec.csv"
    _record(data, 0.02, 8)
    run = FitRun.of(FitRequest(data=(str(data),), output="dz_um", term=("t1_degC", "t2_degC"),
                               orders=(1, 1)))
    record = read_record(str(data))
    specs = [("t1_degC", {"t1_degC": 1.0}), ("t2_degC", {"t2_degC": 1.0})]
    out = fit_fallbacks(run, [record], [record.column("dz_um")], specs, [], [],
                        reads={"t1_degC"})
    assert not out.models
    assert out.notes == ["no fallback without t1_degC: no term is left without it"]


def test_the_veto_asked_quietly_says_the_same_and_counts_nothing() -> None:
    """A selection asks ahead whether every final estimate is refused
    (`models.identify.structures`): `CheckVeto.quietly` says what the veto
    says without counting it among `vetoed` (whose first entry fit prints)."""
    from compd.offline.fit_checks import CheckVeto
    from models.identify.output_error import OeModel

    veto = CheckVeto([("t1", {"t1": 1.0})], [True], [1.0], 1.0, 60.0)
    alternating = OeModel(nums=((0.1,),), dens=((1.0, 0.6),), groups=((0,),))
    said = veto.quietly(alternating)
    assert said is not None and "negative real pole" in said and veto.vetoed == []
    assert veto(alternating) == said and len(veto.vetoed) == 1
    fine = OeModel(nums=((0.1,),), dens=((1.0, -0.9),), groups=((0,),))
    assert veto.quietly(fine) is None and veto(fine) is None and len(veto.vetoed) == 1
