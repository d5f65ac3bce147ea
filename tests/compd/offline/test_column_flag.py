"""One meaning per flag: `--column` names the measured CSV column in `compd
fit` and `compd replay`; `--output` (a file in `compd export`) still works
there, with one deprecation line on stderr, and means the same."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from compd.cli import main


@pytest.fixture(scope="module")
def record(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("rec") / "constant.csv"
    assert main(["sim", "--record", str(path), "--program", "constant", "--hours", "2",
                 "--period-s", "60"]) == 0
    return path


def test_fit_and_replay_take_column(record: Path, tmp_path: Path,
                                    capsys: pytest.CaptureFixture[str]) -> None:
    model = tmp_path / "plant.toml"
    capsys.readouterr()
    assert main(["fit", str(record), "--column", "dz_um", "--term", "bearing",
                 "-o", str(model)]) == 0
    assert model.is_file() and "deprecated" not in capsys.readouterr().err
    assert main(["replay", str(model), str(record), "--column", "dz_um", "--json"]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["fit_percent"] > 50.0 and err == ""


@pytest.mark.parametrize("command", ["fit", "replay"])
def test_the_old_spelling_works_with_one_deprecation_line(
        command: str, record: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    argv = (["fit", str(record), "--output", "dz_um", "--term", "bearing", "--json",
             "-o", str(tmp_path / "m.toml")]
            if command == "fit" else
            ["replay", "sim_machine", str(record), "--output", "dz_um", "--json"])
    capsys.readouterr()
    assert main(argv) == 0
    out, err = capsys.readouterr()
    json.loads(out)  # stdout stays machine output
    # one deprecation line, first (fit may add its own notes, e.g. why it fell back)
    lines = err.splitlines()
    assert lines[0] == f"compd {command}: --output is deprecated, use --column (same meaning)"
    assert sum("deprecated" in line for line in lines) == 1


def test_the_help_names_column(capsys: pytest.CaptureFixture[str]) -> None:
    for command in ("fit", "replay"):
        with pytest.raises(SystemExit):
            main([command, "--help"])
        assert "--column COLUMN, --output COLUMN" in capsys.readouterr().out
