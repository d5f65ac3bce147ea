"""A config's mistakes all at once with their key paths and a "did you mean",
and `compd schema`: the JSON Schema editors validate the TOML with, which
every example config satisfies and which refuses what the loader refuses."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import jsonschema
import pytest

from compd.cli import main
from compd.config.loader import load_config
from compd.errors import ConfigError
from compd.sysexits import EX_CONFIG
from tests.shipped import EXAMPLES as SHIPPED_EXAMPLES

EXAMPLES = sorted(SHIPPED_EXAMPLES.glob("*.toml"))

TWO_MISTAKES = """
[machine]
name = "m"
perod_s = 1.0

[controller]
protocol = "modbus"
endpoint = "modbus://127.0.0.1:5020"

[channels.bearing]
address = { kind = "input", address = 0, type = "int16", scale = 0.1 }
unit = "degC"
range = [-20.0, 150.0]
rnage = [0.0, 1.0]

[model]
file = "sp2"

[output]
offset = { kind = "holding", address = 0, type = "float32" }
limit_um = -5
slew_um_s = 1.0
"""


@pytest.fixture(scope="module")
def schema() -> dict[str, object]:
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert main(["schema"]) == 0
    doc: dict[str, object] = json.loads(buf.getvalue())
    jsonschema.Draft202012Validator.check_schema(doc)
    return doc


def test_every_mistake_is_reported_with_its_key_and_a_suggestion(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "compd.toml"
    path.write_text(TWO_MISTAKES, encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert info.value.key == "machine.perod_s"
    assert main(["check", str(path)]) == EX_CONFIG
    err = capsys.readouterr().err
    assert err.count("\n") == 1  # one line, every mistake on it
    assert "3 mistakes" in err
    assert "machine.perod_s: unknown key (did you mean 'period_s'?)" in err
    assert "channels.bearing.rnage: unknown key (did you mean 'range'?)" in err
    assert "output.limit_um:" in err


def test_an_unknown_key_far_from_every_known_one_gets_no_guess(tmp_path: Path) -> None:
    path = tmp_path / "compd.toml"
    path.write_text(TWO_MISTAKES.replace("perod_s = 1.0", "").replace("rnage", "zzzzzz")
                    .replace("limit_um = -5", "limit_um = 5"), encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert str(info.value) == "channels.bearing.zzzzzz: unknown key"


@pytest.mark.parametrize("example", EXAMPLES, ids=[p.stem for p in EXAMPLES])
def test_the_examples_validate_against_the_printed_schema(example: Path,
                                                           schema: dict[str, object]) -> None:
    doc = tomllib.loads(example.read_text(encoding="utf-8"))
    jsonschema.validate(doc, schema, cls=jsonschema.Draft202012Validator)


def test_the_schema_refuses_what_the_loader_refuses(schema: dict[str, object]) -> None:
    doc = tomllib.loads(TWO_MISTAKES)
    problems = {(*e.absolute_path, e.validator)
                for e in jsonschema.Draft202012Validator(schema).iter_errors(doc)}
    assert ("machine", "additionalProperties") in problems
    assert ("output", "limit_um", "exclusiveMinimum") in problems
    assert len(EXAMPLES) == 5  # one per protocol
