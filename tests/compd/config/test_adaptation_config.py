"""`[adaptation]` in the config: what it loads into, and every refusal naming its key."""

from __future__ import annotations

from pathlib import Path

import pytest

from compd.cli import main
from compd.config.loader import PROBE_NAMES, load_config
from compd.core.cycle import params_from_config
from compd.errors import EX_CONFIG, ConfigError
from tests.configs import MINIMAL

ADAPTATION = """
[adaptation]
enabled = true
mode = "apply"
probe_value = { kind = "input", address = 12, type = "float32" }
probe_counter = { kind = "input", address = 14, type = "uint16" }
probe_noise_um = 0.8
"""


def _load(tmp_path: Path, text: str) -> object:
    p = tmp_path / "compd.toml"
    p.write_text(text, encoding="utf-8")
    return load_config(p)


def test_adaptation_loads_its_addresses_and_settings(tmp_path: Path) -> None:
    cfg = _load(tmp_path, MINIMAL + ADAPTATION)
    assert set(cfg.probes) == set(PROBE_NAMES)  # type: ignore[attr-defined]
    params = params_from_config(cfg)  # type: ignore[arg-type]
    assert params.adaptation is not None and params.adaptation.mode == "apply"
    assert params.adaptation.measures == "residual"  # the default: a compensating machine
    assert params.adaptation.params.probe_noise_um == 0.8
    assert params.adaptation.params.gate_sigma == 4.0  # the estimator's default


def test_adaptation_off_reads_no_probe(tmp_path: Path) -> None:
    cfg = _load(tmp_path, MINIMAL + ADAPTATION.replace("enabled = true", "enabled = false"))
    assert cfg.probes == {}  # type: ignore[attr-defined]
    assert params_from_config(cfg).adaptation is None  # type: ignore[arg-type]


@pytest.mark.parametrize(("change", "key", "words"), [
    (("probe_counter = { kind = \"input\", address = 14, type = \"uint16\" }\n", ""),
     "adaptation.probe_counter", "required when adaptation is enabled"),
    (("probe_noise_um = 0.8", "probe_noise_um = -1"), "adaptation.probe_noise_um", "within"),
    (("probe_noise_um = 0.8", "gate_sigma = 0"), "adaptation.gate_sigma", "within 1"),
    (('mode = "apply"', 'mode = "on"'), "adaptation.mode", "shadow"),
    (("address = 12, type = \"float32\"", "address = 12, type = \"float99\""),
     "adaptation.probe_value", ""),
    (("probe_noise_um = 0.8", "probe_nosie_um = 0.8"), "adaptation.probe_nosie_um", ""),
])
def test_a_bad_adaptation_setting_is_refused_by_name(tmp_path: Path, change: tuple[str, str],
                                                     key: str, words: str) -> None:
    text = MINIMAL + ADAPTATION.replace(*change)
    with pytest.raises(ConfigError) as info:
        _load(tmp_path, text)
    assert key in str(info.value) and words in str(info.value)


def test_check_exits_78_on_a_bad_adaptation_setting(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    p = tmp_path / "compd.toml"
    p.write_text(MINIMAL + ADAPTATION.replace("probe_noise_um = 0.8", "max_step_um = nan"),
                 encoding="utf-8")
    assert main(["check", str(p)]) == EX_CONFIG
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "adaptation.max_step_um" in err[0]
