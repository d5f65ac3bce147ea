"""Bounded TOML and JSON nesting: a file nested hundreds of
levels deep is one NestingError, never a RecursionError; brackets inside
strings and comments do not count; real files are read as tomllib reads them."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from compd.infiles import load_model
from models import tomltext
from models.nesting import (
    MAX_NESTING,
    NestingError,
    document_depth,
    loads_json,
    loads_toml,
    text_depth,
)
from tests.shipped import EXAMPLES, LIBRARY

ROOT = Path(__file__).resolve().parents[2]
DEEP = 900  # deep enough that tomllib and json recurse past Python's limit


@pytest.mark.parametrize("text", [
    "a = " + "[" * DEEP + "]" * DEEP,
    "a = " + "{b = " * DEEP + "1" + "}" * DEEP,
    "a." * DEEP + "b = 1",  # dotted keys nest without a bracket
    "[" + ".".join(["t"] * DEEP) + "]\nx = 1",
    "a = " + "[" * (MAX_NESTING + 1) + "]" * (MAX_NESTING + 1),
])
def test_deep_toml_is_one_nesting_error(text: str) -> None:
    with pytest.raises(NestingError, match=f"at most {MAX_NESTING} are accepted"):
        loads_toml(text)


def test_the_deepest_accepted_document_reads() -> None:
    text = "a = " + "[" * MAX_NESTING + "1" + "]" * MAX_NESTING
    assert loads_toml(text) == tomllib.loads(text)


@pytest.mark.parametrize("text", [
    'a = "' + "[" * DEEP + '"',
    "a = '" + "{" * DEEP + "'",
    'a = """\n' + "[" * DEEP + '\n"""',
    "a = '''\n" + "[" * DEEP + "\n'''",
    'a = "\\"' + "[" * DEEP + '"',  # an escaped quote does not end the string
    'a = """x""""\nb = "' + "[" * DEEP + '"',  # """ may end in up to two more quotes
    "# " + "[" * DEEP + "\na = 1",
])
def test_brackets_in_strings_and_comments_do_not_count(text: str) -> None:
    assert text_depth(text) == 0
    assert loads_toml(text) == tomllib.loads(text)


def test_every_shipped_config_and_model_reads_as_tomllib_reads_it() -> None:
    files = [*EXAMPLES.glob("*.toml"), *LIBRARY.glob("*.toml")]
    assert len(files) >= 5
    for path in files:
        text = path.read_text(encoding="utf-8")
        assert loads_toml(text) == tomllib.loads(text), path


def test_deep_json_is_one_nesting_error() -> None:
    with pytest.raises(NestingError):
        loads_json("[" * DEEP * 10 + "]" * DEEP * 10)
    with pytest.raises(NestingError):
        loads_json('{"a": ' * DEEP + "1" + "}" * DEEP)
    assert loads_json('{"a": "[[[[", "b": [[1]]}') == {"a": "[[[[", "b": [[1]]}
    with pytest.raises(json.JSONDecodeError):
        loads_json("{")


def test_a_recursion_error_in_the_parser_is_a_nesting_error() -> None:
    def recursing(_: str) -> object:
        raise RecursionError("maximum recursion depth exceeded")

    with pytest.raises(NestingError, match="too deep to parse"):
        loads_json("[]", parse=recursing)


def test_document_depth_counts_containers_below_the_root() -> None:
    assert document_depth({}) == 0
    assert document_depth({"a": 1}) == 0
    assert document_depth({"a": [1, {"b": [2]}]}) == 3


def test_a_deep_model_file_is_an_input_error(tmp_path: Path) -> None:
    from compd.infiles import InputError

    path = tmp_path / "deep.toml"
    path.write_text("a = " + "[" * DEEP + "]" * DEEP, encoding="utf-8")
    with pytest.raises(InputError, match=r"deep\.toml: the model file has arrays and tables"):
        load_model(path)


def test_a_deep_checkpoint_is_a_checkpoint_error(tmp_path: Path) -> None:
    from compd.runtime.checkpoint import CheckpointError, load_checkpoint

    path = tmp_path / "checkpoint.json"
    path.write_text('{"version": ' + "[" * DEEP * 10 + "]" * DEEP * 10 + "}", encoding="utf-8")
    path.chmod(0o600)
    with pytest.raises(CheckpointError, match="nested more than"):
        load_checkpoint(path)


#: TOML's structural characters, quotes, escapes and comments, in any order
_TOML_ALPHABET = st.sampled_from([*"[]{}\"'#\\\n =,.ab1", '"""', "'''", "a = ", "\n[t]\n"])


@settings(max_examples=150, deadline=None, derandomize=True)
@given(st.lists(_TOML_ALPHABET, max_size=60).map("".join))
def test_the_scan_never_refuses_what_tomllib_reads_shallow(text: str) -> None:
    """Whatever tomllib reads (and nests no deeper than the bound), the
    bounded reader reads the same; whatever it refuses, the bounded reader
    refuses too (a TOMLDecodeError or a NestingError, never anything else)."""
    try:
        expected = tomllib.loads(text)
    except tomllib.TOMLDecodeError:
        with pytest.raises((tomllib.TOMLDecodeError, NestingError)):
            loads_toml(text)
        return
    if document_depth(expected) <= MAX_NESTING and text_depth(text) <= MAX_NESTING:
        assert loads_toml(text) == expected
    assert text_depth(text) >= 0


_TEXT = st.text(alphabet=st.sampled_from([*"[]{}\"'#\\\n\t ab", "\u00b5"]), max_size=20)
_KEYS = st.text(alphabet=st.sampled_from([*"ab_-[ \"", "\u00b5"]), max_size=4)
_VALUES = st.recursive(st.one_of(_TEXT, st.integers(-5, 5), st.booleans()),
                       lambda inner: st.one_of(st.lists(inner, max_size=3),
                                               st.dictionaries(_KEYS, inner, max_size=3)),
                       max_leaves=10)


@settings(max_examples=150, deadline=None, derandomize=True)
@given(st.dictionaries(_KEYS, _VALUES, max_size=4))
def test_documents_written_with_brackets_and_odd_keys_read_as_written(doc: dict[str, Any]) -> None:
    text = tomltext.dumps(doc)
    assert loads_toml(text) == tomllib.loads(text) == doc
