"""Quality figures, the numpy bank, model files and the bundled library."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from compd.infiles import InputError, load_model
from models.bank import TfBank
from models.errors import ModelError
from models.modelfile import (
    dumps_model,
    library_names,
    model_document,
    parse_model,
)
from models.quality import quality
from models.tf import TransferFunction
from tests.models.paper_tfs import PAPER_TFS


def test_quality_figures_by_hand() -> None:
    measured = np.array([0.0, 10.0, 20.0, 10.0])
    simulated = np.array([1.0, 9.0, 18.0, 10.0])
    q = quality(measured, simulated)
    assert q.residue_min_um == -1.0 and q.residue_max_um == 2.0
    assert q.dpk_um == 3.0
    assert q.range_reduction == pytest.approx(20.0 / 3.0)
    spread = math.sqrt(100 + 0 + 100 + 0)
    assert q.fit_percent == pytest.approx((1 - math.sqrt(1 + 1 + 4 + 0) / spread) * 100)


def test_bank_matches_individual_filters() -> None:
    names = sorted(PAPER_TFS)
    filters = [TransferFunction(*PAPER_TFS[n], name=n) for n in names]
    bank = TfBank.from_filters(filters)
    rng = np.random.default_rng(5)
    u = rng.normal(0, 1, (500, len(names)))
    ys = np.array([bank.step(row).copy() for row in u])
    for j, f in enumerate(filters):
        np.testing.assert_allclose(ys[:, j], f.simulate(u[:, j]), rtol=1e-12, atol=1e-12)


def test_bank_refuses_b0_zero() -> None:
    with pytest.raises(ModelError, match="b0 = 0"):
        TfBank([[1.0, 0.0]], [[0.0, 1.0]])


@pytest.mark.parametrize("name", library_names())
def test_library_models_load_and_round_trip_through_toml(name: str, tmp_path: Path) -> None:
    model = load_model(name)
    text = dumps_model(model_document(model))
    (tmp_path / "m.toml").write_text(text)
    again = load_model(tmp_path / "m.toml")
    sample = {ch: 21.0 for ch in model.channels} | {"clamp_gain": 2.2}
    refs = {ch: 20.0 for ch in model.reference_channels}
    model.set_references(refs)
    again.set_references(refs)
    assert [model.step(sample) for _ in range(50)] == [again.step(sample) for _ in range(50)]


def test_library_holds_the_papers_models() -> None:
    assert {"sp1", "sp2", "sp3", "sp2_simplified", "sp3_simplified",
            "lathe_milling_turning"} <= set(library_names())
    assert load_model("sp2_simplified").terms[0].gain == 1.75
    assert load_model("sp3_simplified").terms[0].gain == 1.25
    assert load_model("lathe_milling_turning").terms[1].gain_channel == "clamp_gain"


def _doc(**term: object) -> dict[str, object]:
    base: dict[str, object] = {"name": "t", "inputs": {"x": 1.0}, "a": ["1"], "b": ["1", "-0.5"]}
    base.update(term)
    return {"model": {"name": "m", "period_s": 1.0}, "terms": [base]}


@pytest.mark.parametrize(("doc", "message"), [
    (_doc(colour="red"), r"terms\[0\]: unknown key\(s\) \['colour'\]"),
    (_doc(kind="neural"), r"terms\[0\].kind: unknown kind"),
    (_doc(inputs={}), r"terms\[0\].inputs"),
    (_doc(b=["1", "-1.2"]), "unstable"),
    (_doc(gain="big"), r"terms\[0\].gain: must be a finite number"),
    (_doc(gain=1.0, gain_channel="g"), "either gain or gain_channel"),
    ({"model": {"period_s": 0}, "terms": []}, r"model.model.period_s: 0.0 s is outside 0.01"),
    ({"model": {}, "terms": []}, "at least one"),
    ({"model": {"channels": ["y"]}, "terms": [_doc()["terms"][0]]},  # type: ignore[index]
     r"term 't': unknown channel"),
    (_doc(kind="greybox", p=[-1e-3, 1.0, 0.0, -1e-3, 1.0, 0.0]), "switch_channel"),
    (_doc(kind="mbotv", alpha=1.0, beta=0.0, gamma=0.5), "exactly one of k or tau_s"),
])
def test_model_documents_are_checked_key_by_key(doc: dict[str, object], message: str) -> None:
    for kind_key in ("a", "b"):
        term = doc["terms"][0] if doc["terms"] else {}  # type: ignore[index]
        if isinstance(term, dict) and term.get("kind") in ("greybox", "mbotv"):
            term.pop(kind_key, None)
    with pytest.raises(ModelError, match=message):
        parse_model(doc)


def test_unreadable_and_invalid_files(tmp_path: Path) -> None:
    """The one model loader (compd.infiles) says which file and why, with the exit
    code: 66 for a file that is not there, 65 for one that is not a model."""
    with pytest.raises(InputError, match="cannot read the model file") as missing:
        load_model(tmp_path / "missing.toml")
    assert missing.value.code == 66
    bad = tmp_path / "bad.toml"
    bad.write_text("[model\nname=")
    with pytest.raises(InputError, match="not valid TOML") as invalid:
        load_model(bad)
    assert invalid.value.code == 65
    big = tmp_path / "big.toml"
    big.write_bytes(b"#" * ((1 << 20) + 1))
    with pytest.raises(InputError, match=r"at most 1\.0 MiB"):
        load_model(big)
