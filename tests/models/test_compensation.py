"""Compensation models: terms, references, gains from channels, state, bad terms."""

from __future__ import annotations

import numpy as np
import pytest

from compd.infiles import load_model
from models.compensation import CompensationModel, Term
from models.errors import ModelError
from models.tf import TransferFunction
from tests.models.paper_tfs import PAPER_TFS


def _sp2() -> CompensationModel:
    model = load_model("sp2")
    model.set_references({"bearing": 22.0, "ambient": 20.0})
    return model


def test_sp2_first_sample_worked_number() -> None:
    model = _sp2()
    assert model.step({"bearing": 23.0, "ambient": 20.0}) == pytest.approx(16.0005)
    assert model.contributions == [pytest.approx(16.0005), 0.0]


def test_model_equals_sum_of_its_terms_stepped_alone() -> None:
    rng = np.random.default_rng(3)
    bearing = 22.0 + np.cumsum(rng.normal(0.001, 0.01, 3000))
    ambient = 20.0 + np.cumsum(rng.normal(0, 0.005, 3000))
    model = _sp2()
    out = [model.step({"bearing": b, "ambient": a}) for b, a in zip(bearing, ambient, strict=True)]
    sp = TransferFunction(*PAPER_TFS["eps_SP2"], name="s").simulate(bearing - 22.0)
    amb = TransferFunction(*PAPER_TFS["eps_amb"], name="a").simulate(ambient - 20.0)
    np.testing.assert_allclose(out, sp + amb, rtol=1e-12, atol=1e-12)


def test_gain_read_from_a_channel_at_run_time() -> None:
    model = load_model("lathe_milling_turning")
    model.set_references({"bearing": 20.0, "column": 20.0, "table": 20.0})
    y1 = model.step({"bearing": 20.0, "column": 20.0, "table": 21.0, "clamp_gain": 2.2})
    assert y1 == pytest.approx(2.2 * -82.41672)
    model.reset()
    y2 = model.step({"bearing": 20.0, "column": 20.0, "table": 21.0, "clamp_gain": 1.0})
    assert y2 == pytest.approx(-82.41672)


def test_signed_channel_combination() -> None:
    model = load_model("lathe_milling_turning")
    model.set_references({"bearing": 20.0, "column": 20.0, "table": 20.0})
    # bearing and column rising together: the milling term sees no difference
    y = model.step({"bearing": 21.0, "column": 21.0, "table": 21.0, "clamp_gain": 2.2})
    assert y == 0.0


def test_whole_model_state_round_trip_continues_exactly() -> None:
    rng = np.random.default_rng(4)
    samples = [{"bearing": 22 + 0.01 * i + rng.normal(0, 0.05), "ambient": 20 + rng.normal(0, 0.1)}
               for i in range(2000)]
    whole = _sp2()
    expected = [whole.step(s) for s in samples]
    first = _sp2()
    head = [first.step(s) for s in samples[:700]]
    state = first.export_state()
    again = load_model("sp2")
    again.import_state(state)
    tail = [again.step(s) for s in samples[700:]]
    assert head + tail == expected


def test_steady_state_of_a_warm_machine() -> None:
    model = _sp2()
    warm = {"bearing": 27.0, "ambient": 21.0}
    y0 = model.steady_state(warm)
    assert y0 == pytest.approx(5 * 17.647058823529 + 1 * -16.7333333333, rel=1e-9)
    for _ in range(100):
        assert model.step(warm) == pytest.approx(y0, rel=1e-12)


def test_references_are_required_and_named() -> None:
    model = load_model("sp2")
    with pytest.raises(ModelError, match=r"no reference value for channel\(s\) \['ambient'\]"):
        model.set_references({"bearing": 20.0})


def test_unknown_channel_in_a_term_is_refused_with_the_term_named() -> None:
    model = load_model("sp2")
    with pytest.raises(ModelError, match=r"term 'ambient': unknown channel\(s\) \['ambient'\]"):
        model.check_channels(["bearing", "column"])


def test_bad_terms() -> None:
    tf = TransferFunction(["1"], ["1", "-0.5"], "t")
    with pytest.raises(ModelError, match="at least one input"):
        Term("t", {}, tf)
    with pytest.raises(ModelError, match="coefficient must be a finite"):
        Term("t", {"x": float("nan")}, tf)
    with pytest.raises(ModelError, match="duplicate term"):
        CompensationModel([Term("t", {"x": 1.0}, tf), Term("t", {"y": 1.0}, tf)], 1.0)
    with pytest.raises(ModelError, match="at least one term"):
        CompensationModel([], 1.0)


def test_fresh_is_the_same_model_with_a_state_of_its_own() -> None:
    """`fresh` copies the description; stepping the copy leaves the original at rest
    (each transfer function's step is a closure over its own state)."""
    from models.modelfile import model_document

    original = load_model("sp2")
    original.set_references({"bearing": 20.0, "ambient": 20.0})
    copy = original.fresh()
    assert model_document(copy) == model_document(original)
    assert copy.references == {}
    copy.set_references({"bearing": 20.0, "ambient": 20.0})
    ys = [copy.step({"bearing": 21.0, "ambient": 20.0}) for _ in range(5)]
    assert ys[0] == pytest.approx(16.0005)
    assert original.export_state()["terms"] == original.fresh().export_state()["terms"]
    assert all(z == 0.0 for t in original.export_state()["terms"].values() for z in t["z"])
    assert original.step({"bearing": 21.0, "ambient": 20.0}) == ys[0]  # from rest, as the copy
