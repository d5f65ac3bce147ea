"""The loader takes ``[output.axes.<axis>]`` (`compd.config.loader`): each axis's
models built as ``[model]``'s are, its stage's rates, each refusal naming the key."""

from __future__ import annotations

from pathlib import Path

import pytest

from compd.config.loader import load_config
from compd.errors import ConfigError
from tests.compd.axes_helpers import axes_config_text, write_axes_config


def _error(tmp_path: Path, text: str) -> ConfigError:
    p = tmp_path / "compd.toml"
    p.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_config(p)
    return info.value


def test_an_axis_with_value_and_slope_models_loads(tmp_path: Path) -> None:
    cfg = load_config(write_axes_config(tmp_path, value_slew=0.5, slope_slew=0.25))
    axes = cfg.axes
    assert axes is not None and axes.axes == ("x",)
    models = axes.models["x"]
    assert models.value.channels == {"column", "screw_bearing", "ambient"}
    assert models.slope is not None and models.slope.channels == {"nut", "screw_bearing"}
    assert models.value.calibration_reference == {"column": 20.0, "screw_bearing": 20.0,
                                                  "ambient": 20.0}
    stage = axes.stages["x"]
    assert (stage.slew_um_s, stage.slope_slew_um_m_s) == (0.5, 0.25)
    # the parameters are driver outputs beside the offset; TwinCAT's grid is the quantum
    assert {"x_comp_value", "x_comp_slope", "x_comp_reference", "offset"} <= set(cfg.outputs)
    assert axes.quanta["x"] == (0.1, 1.0)


def test_without_a_slope_model_no_slope_rate_is_needed(tmp_path: Path) -> None:
    text = axes_config_text()
    text = text[:text.index("[output.axes.x.slope_model]")] + text[text.index("[faults]"):]
    text = text.replace("slope_slew_um_m_s = 1.0\n", "")
    p = tmp_path / "c.toml"
    p.write_text(text, encoding="utf-8")
    axes = load_config(p).axes
    assert axes is not None and axes.models["x"].slope is None


@pytest.mark.parametrize(("edit", "key", "reason"), [
    (("inputs = { nut = 5.0", "inputs = { spindle = 5.0"),
     "output.axes.x.slope_model.terms", "spindle"),
    (("slew_um_s = 1.0\nslope_slew", "slope_slew"), "output.axes.x.slew_um_s",
     "required key is missing"),
    (("slope_slew_um_m_s = 1.0\n", ""), "output.axes.x.slope_slew_um_m_s", "slope_model"),
    (("slope_slew_um_m_s = 1.0\n", "slope_slew_um_m_s = 0.0\n"),
     "output.axes.x.slope_slew_um_m_s", "must be > 0"),
    (("[output.axes.x.model]\n", "[output.axes.x.other]\n"), "output.axes.x.other",
     "unknown key"),
    (('[output.axes.x.model]\n', '[output.axes.x.model]\nfile = "nowhere.toml"\n'),
     "output.axes.x.model", "either file"),
    (('[output.axes.x.slope_model]\n', '[output.axes.x.slope_model]\nperiod_s = 2.0\n'),
     "output.axes.x.slope_model.terms", "period_s"),
    (("value = { kind = \"holding\", address = 34", "value = { kind = \"holding\", address = 0"),
     "output.axes.x.value", "output.offset"),
    (("value_limit_um = 200.0", "value_limit_um = 200.0\ndeadband_um = 300.0"),
     "output.axes.x.deadband_um", "below the limit"),
])
def test_refusals_name_the_key(tmp_path: Path, edit: tuple[str, str], key: str,
                               reason: str) -> None:
    text = axes_config_text()
    assert edit[0] in text
    err = _error(tmp_path, text.replace(edit[0], edit[1], 1))
    assert err.key == key, err
    assert reason in err.reason, err


def test_an_axis_without_a_value_model_is_refused(tmp_path: Path) -> None:
    text = axes_config_text()
    text = text[:text.index("[output.axes.x.model]")] + text[
        text.index("[output.axes.x.slope_model]"):]
    err = _error(tmp_path, text)
    assert err.key == "output.axes.x.model" and "required" in err.reason


def test_a_recorder_only_config_ignores_its_axes(tmp_path: Path) -> None:
    text = axes_config_text().replace("[output]\n", "[output]\nenabled = false\n")
    p = tmp_path / "c.toml"
    p.write_text(text, encoding="utf-8")
    cfg = load_config(p)
    assert cfg.axes is None and "x_comp_value" not in cfg.outputs
