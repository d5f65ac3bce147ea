"""`compd check` tells a daemon config from a model file by the tables it holds: a
config missing its [controller] is told what it misses, not read as a model."""

from __future__ import annotations

from pathlib import Path

import pytest

from compd.cli import main
from compd.sysexits import EX_CONFIG


@pytest.mark.parametrize("text", [
    "[output.axes.x]\nvalue_limit_um = 50\n",
    "[channels.t1]\nunit = \"degC\"\n",
    "[recorder]\nenabled = false\n",
])
def test_a_config_without_its_controller_is_told_so(
        text: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "partial.toml"
    path.write_text(text)
    assert main(["check", str(path)]) == EX_CONFIG
    [line] = capsys.readouterr().err.strip().splitlines()
    assert "controller: required key is missing" in line
    assert "unknown key" not in line  # not the model file's complaint


def test_a_model_file_is_still_read_as_a_model(tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "m.toml"
    path.write_text('[model]\nname = "m"\nperiod_s = 1.0\n'
                    '[[terms]]\nname = "a"\ninputs = { t1 = 1.0 }\n'
                    'kind = "tf"\nb = [0.1]\na = [1.0, -0.9]\n')
    rc = main(["check", str(path)])
    out, err = capsys.readouterr()
    assert "controller" not in err
    assert rc == 0, err
    assert "model 'm'" in out
