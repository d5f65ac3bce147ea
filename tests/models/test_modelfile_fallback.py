"""A model file's [[fallback]] tables: read, written back bit for bit, and
refused with the key path when a fallback could not stand in for its channel."""

from __future__ import annotations

import tomllib

import pytest

from models.errors import ModelError
from models.modelfile import dumps_model, model_document, parse_model
from tests.compd.core.fallback_helpers import SP2_WITH_FALLBACKS, sp2_with_fallbacks


def test_fallbacks_read_and_round_trip() -> None:
    model = sp2_with_fallbacks()
    assert sorted(model.fallbacks) == ["ambient", "bearing"]
    assert model.fallbacks["ambient"].channels == {"bearing"}
    text = dumps_model(model_document(model))
    again = parse_model(tomllib.loads(text))
    assert model_document(again) == model_document(model)


@pytest.mark.parametrize(("edit", "message"), [
    (('lost = "ambient"', 'lost = "column"'), "fallback[0].lost: the model reads no channel"),
    (('inputs = { bearing = 1.0 }\na = ["16.5"', 'inputs = { ambient = 1.0 }\na = ["16.5"'),
     "fallback[0].terms: the fallback for 'ambient' reads 'ambient'"),
    (('lost = "bearing"', 'lost = "ambient"'), "fallback[1].lost: a second fallback"),
    (('model = { name = "without ambient", period_s = 1.0 }',
      'model = { name = "without ambient", period_s = 2.0 }'), "fallback[0].model.period_s"),
    (('lost = "ambient"', 'lost = "ambient"\ncolour = 1'), "fallback[0]: unknown key(s)"),
])
def test_a_fallback_that_cannot_stand_in_is_refused(edit: tuple[str, str], message: str) -> None:
    old, new = edit
    assert old in SP2_WITH_FALLBACKS
    with pytest.raises(ModelError, match=message.replace("(", r"\(").replace(")", r"\)")
                       .replace("[", r"\[").replace("]", r"\]")):
        sp2_with_fallbacks(SP2_WITH_FALLBACKS.replace(old, new, 1))
