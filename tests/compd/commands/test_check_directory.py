"""`compd check DIR/` validates every *.toml in DIR as `compd run DIR/` does
(one machine each, the same refusals), and `compd check NAME` for a name that
is neither a file nor a bundled model lists the bundled names."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest

from compd.cli import main
from compd.sysexits import EX_CONFIG, EX_NOINPUT
from models.modelfile import library_names
from tests.shipped import EXAMPLES

ROOT = Path(__file__).resolve().parents[3]


def _fleet(tmp_path: Path, *names: str) -> Path:
    d = tmp_path / "machines"
    d.mkdir()
    for name in names:
        shutil.copy(EXAMPLES / f"{name}.toml", d / f"{name}.toml")
    return d


def test_check_dir_reports_every_machine(tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    d = _fleet(tmp_path, "modbus", "s7")
    assert main(["check", str(d) + "/"]) == 0, capsys.readouterr().err
    out = capsys.readouterr().out
    assert "2 machine(s)" in out
    assert f"config {d / 'modbus.toml'}: OK" in out and f"config {d / 's7.toml'}: OK" in out


def test_check_dir_json_is_one_object(tmp_path: Path,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    d = _fleet(tmp_path, "modbus", "opcua")
    assert main(["check", str(d), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert [m["machine"] for m in doc["machines"]] == ["sim-modbus", "sim-opcua"]


def test_check_dir_refuses_what_run_dir_refuses(tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    d = _fleet(tmp_path, "modbus", "focas")  # focas: the vendor library is not there
    for command in ("check", "run"):
        assert main([command, str(d)]) == EX_CONFIG
        err = capsys.readouterr().err
        assert "focas.toml" in err and "library_path" in err
    # two files for one machine: refused by both alike
    (tmp_path / "x").mkdir()
    d2 = _fleet(tmp_path / "x", "modbus")
    text = (d2 / "modbus.toml").read_text(encoding="utf-8")
    (d2 / "other.toml").write_text(re.sub(r'(?m)^endpoint = .*$',
                                          'endpoint = "modbus://127.0.0.1:5021"', text),
                                   encoding="utf-8")
    assert main(["check", str(d2)]) == EX_CONFIG
    check_err = capsys.readouterr().err
    assert main(["run", str(d2)]) == EX_CONFIG
    assert capsys.readouterr().err == check_err


def test_check_an_empty_dir_is_refused_as_run_refuses_it(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check", str(tmp_path)]) == EX_CONFIG
    assert "no *.toml machine configs" in capsys.readouterr().err


def test_an_unknown_name_lists_the_bundled_models(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check", "sp9"]) == EX_NOINPUT
    [line] = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("compd check: sp9: no such file, nor a bundled model")
    for name in library_names():
        assert name in line
    assert "sim_machine" in line and "sp2" in line
