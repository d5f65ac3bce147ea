"""A channel's name is an identifier: it is a record's column, a metric's label and
an OPC UA node, and a dot would read as another column's prefix (an export's
``valid.<channel>``, an axis's ``x.state``)."""

from __future__ import annotations

from pathlib import Path

import pytest

from compd.cli import main
from compd.sysexits import EX_CONFIG

CONFIG = """[controller]
protocol = "modbus"
endpoint = "modbus://127.0.0.1:5020"
[channels.{name}]
address = {{ kind = "holding", address = 1, type = "float32" }}
unit = "degC"
range = [0.0, 100.0]
"""


@pytest.mark.parametrize("name", ['"x.state"', '"valid.t1"', '"t 1"', '"1st"', '"ä"',
                                  '"a\\nb"', '""', '"' + "a" * 65 + '"'])
def test_a_channel_name_that_is_no_identifier_is_refused_in_one_line(
        name: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "c.toml"
    path.write_text(CONFIG.format(name=name), encoding="utf-8")
    assert main(["check", str(path)]) == EX_CONFIG
    [line] = capsys.readouterr().err.strip().splitlines()
    assert "channel" in line and "letters, digits and underscores" in line


@pytest.mark.parametrize("name", ["bearing", "t1_degC", "_spare", "T" + "1" * 63])
def test_identifiers_are_taken(name: str, tmp_path: Path,
                               capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "c.toml"
    path.write_text(CONFIG.format(name=name), encoding="utf-8")
    assert main(["check", str(path)]) == 0, capsys.readouterr().err
    assert f"channel {name}:" in capsys.readouterr().out
