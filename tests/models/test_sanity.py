"""Physically absurd models are refused (and the model content of the
bad-input list)."""

from __future__ import annotations

import math

import pytest

from compd.infiles import load_model
from models.errors import ModelError
from models.modelfile import library_names, parse_model
from models.sanity import (
    DEFAULT_MAX_DC_GAIN_UM,
    DEFAULT_MAX_TIME_CONSTANT_S,
    check_model,
    slowest_time_constant_s,
)


def _model(a: list[str], b: list[str], period_s: float = 1.0, **term: object) -> dict[str, object]:
    return {"model": {"name": "m", "period_s": period_s},
            "terms": [{"name": "spindle", "inputs": {"bearing": 1.0}, "a": a, "b": b, **term}]}


@pytest.mark.parametrize("name", library_names())
def test_every_bundled_model_is_plausible(name: str) -> None:
    check_model(load_model(name))


def test_dc_gain_of_2e307_is_refused_naming_the_term() -> None:
    model = parse_model(_model(["1e308", "-0.9e308"], ["1", "-0.5"]))
    with pytest.raises(ModelError, match=r"term 'spindle': DC gain 2e\+307 µm per unit of "
                                         r"bearing is beyond ±1000"):
        check_model(model)


def test_the_input_coefficient_and_gain_count_in_the_dc_gain() -> None:
    doc = _model(["0.1"], ["1", "-0.9"])  # DC 1 µm/K
    check_model(parse_model(doc))
    doc["terms"][0]["inputs"] = {"bearing": 2000.0}  # type: ignore[index]
    with pytest.raises(ModelError, match="DC gain 2000"):
        check_model(parse_model(doc))
    with pytest.raises(ModelError, match="DC gain -1001"):
        check_model(parse_model(_model(["0.1"], ["1", "-0.9"], gain=-1001.0)))


def test_a_pole_at_0_9999999999_is_refused_by_its_time_constant() -> None:
    # DC 1 µm/K: only the time constant (1e10 s, 317 years) is absurd
    model = parse_model(_model(["0.0000000001"], ["1", "-0.9999999999"]))
    tau = slowest_time_constant_s(model.terms[0].dynamics, 1.0)
    assert tau == pytest.approx(1e10, rel=1e-6)
    with pytest.raises(ModelError, match=r"term 'spindle': slowest time constant 1e\+10 s"):
        check_model(model)
    # the bound is configurable
    check_model(model, max_time_constant_s=2e10)
    assert DEFAULT_MAX_TIME_CONSTANT_S < 1e10 and DEFAULT_MAX_DC_GAIN_UM == 1000.0


def test_grey_box_and_mbotv_time_constants() -> None:
    grey = parse_model({"model": {"period_s": 1.0}, "terms": [
        {"name": "g", "kind": "greybox", "inputs": {"power": 1.0}, "p": [-1e-7, 1e-7, 0.0]}]})
    with pytest.raises(ModelError, match="slowest time constant"):
        check_model(grey)
    mb = parse_model({"model": {"period_s": 1.0}, "terms": [
        {"name": "m", "kind": "mbotv", "inputs": {"t": 1.0}, "alpha": 5.0, "beta": 0.0,
         "gamma": 0.5, "tau_s": 3600.0}]})
    check_model(mb)
    assert slowest_time_constant_s(mb.terms[0].dynamics, 1.0) == pytest.approx(3600.0)


@pytest.mark.parametrize("coefficient", ["1e999999999", "-1e999999999", "1e-999999999", "1e-401",
                                         "1e309", "0e-999999999"])
def test_a_coefficient_beyond_float64_is_a_model_error(coefficient: str) -> None:
    with pytest.raises(ModelError, match="outside the range of a float64"):
        parse_model(_model([coefficient, "-1"], ["1", "-0.5"]))


@pytest.mark.parametrize("period_s", [1e-9, 1e308, 0.001, 7200.0, math.inf])
def test_an_absurd_period_is_refused(period_s: float) -> None:
    with pytest.raises(ModelError, match="period_s"):
        parse_model(_model(["0.1"], ["1", "-0.9"], period_s=period_s))
