"""Every numeric [adaptation] setting and [model] max_dc_gain_um has a physical bound,
refused by name with exit 78 by `compd check` and `compd run` (beyond it the daemon
would die of an OverflowError at start, at the first probe or at a reload; 1e6 bounds
would let six probes push the correction to 192 µm)."""

from __future__ import annotations

from pathlib import Path

import pytest

from compd.cli import main
from compd.config.loader import load_config
from compd.core.cycle import params_from_config
from compd.errors import EX_CONFIG, ConfigError
from tests.compd.config.test_adaptation_config import ADAPTATION
from tests.configs import MINIMAL, write_config

#: settings beyond a bound, and each bound's other side (MINIMAL has output.limit_um = 100)
REFUSED = [
    ("max_total_um = 1e308", "adaptation.max_total_um"),
    ("probe_noise_um = 1e160", "adaptation.probe_noise_um"),
    ("bias_rw_um_per_sqrt_h = 1e160", "adaptation.bias_rw_um_per_sqrt_h"),
    ("gains = true\nmax_gain = 1e200", "adaptation.max_gain"),
    ("gains = true\ngain_rw_per_sqrt_h = 1e160", "adaptation.gain_rw_per_sqrt_h"),
    ("max_total_um = 1e6", "adaptation.max_total_um"),
    ("max_step_um = 1e6", "adaptation.max_step_um"),
    ("gate_sigma = 1e6", "adaptation.gate_sigma"),
    ("gate_sigma = 0.5", "adaptation.gate_sigma"),
    ("probe_noise_um = 0.001", "adaptation.probe_noise_um"),
    ("bias_rw_um_per_sqrt_h = 101.0", "adaptation.bias_rw_um_per_sqrt_h"),
    ("gains = true\nmax_gain = 1.5", "adaptation.max_gain"),
    ("max_total_um = 150.0", "adaptation.max_total_um"),  # beyond output.limit_um
    ("max_step_um = 100.5", "adaptation.max_step_um"),
    ("max_step_um = 0.0", "adaptation.max_step_um"),
    ("gate_sigma = inf", "adaptation.gate_sigma"),
]


def _config(tmp_path: Path, settings: str, model: str = "") -> Path:
    return write_config(tmp_path, base=MINIMAL + ADAPTATION,
                        swap=[('file = "sp2"', f'file = "sp2"\n{model}'),
                              ("probe_noise_um = 0.8", settings)])


@pytest.mark.parametrize(("settings", "key"), REFUSED)
def test_check_refuses_a_setting_beyond_its_bound_by_name(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], settings: str, key: str) -> None:
    path = _config(tmp_path, settings)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert info.value.key == key
    assert main(["check", str(path)]) == EX_CONFIG
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and key in err[0] and "Traceback" not in err[0]


@pytest.mark.parametrize(("settings", "key"), [REFUSED[2], REFUSED[3], REFUSED[0]])
def test_run_refuses_it_with_78_before_it_starts(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], settings: str, key: str) -> None:
    """bias_rw 1e160 and max_gain 1e200: `run` exits 78 with one line, never 1 with a
    traceback."""
    path = _config(tmp_path, settings)
    assert main(["run", str(path)]) == EX_CONFIG
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and key in err[0]


def test_the_model_dc_gain_bound_has_a_cap(tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    path = _config(tmp_path, "probe_noise_um = 0.8", model="max_dc_gain_um = 1e308")
    assert main(["check", str(path)]) == EX_CONFIG
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "model.max_dc_gain_um" in err[0] and "10000" in err[0]
    ok = _config(tmp_path, "probe_noise_um = 0.8", model="max_dc_gain_um = 10000.0")
    section = load_config(ok).raw.model
    assert section is not None and section.max_dc_gain_um == 10000.0


def test_the_bounds_themselves_are_accepted(tmp_path: Path) -> None:
    edges = ("gains = true\nmax_gain = 1.0\ngain_rw_per_sqrt_h = 1.0\ngate_sigma = 10.0\n"
             "max_total_um = 100.0\nmax_step_um = 100.0\nprobe_noise_um = 100.0\n"
             "bias_rw_um_per_sqrt_h = 100.0")
    params = params_from_config(load_config(_config(tmp_path, edges)))
    assert params.adaptation is not None
    p = params.adaptation.params
    assert (p.max_total_um, p.gate_sigma, p.max_gain) == (100.0, 10.0, 1.0)
    low = "gate_sigma = 1.0\nprobe_noise_um = 0.01\nmax_step_um = 0.001\nmax_total_um = 0.001"
    assert load_config(_config(tmp_path, low)).raw.adaptation.gate_sigma == 1.0


def test_the_schema_shows_each_bound_and_why(capsys: pytest.CaptureFixture[str]) -> None:
    from compd.config.schema import AdaptationSection

    props = AdaptationSection.model_json_schema()["properties"]
    gate = next(s for s in props["gate_sigma"]["anyOf"] if s.get("type") == "number")
    assert (gate["minimum"], gate["maximum"]) == (1.0, 10.0) and "σ" in gate["description"]
