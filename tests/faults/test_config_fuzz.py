"""Fuzzed configurations and model coefficient tables (hypothesis): structured
mutations of a valid config per protocol (drop, replace, retype keys, add
unknown ones, random TOML values), random bytes and text as a config file,
and random inline model terms. Whatever comes in, `parse_config` /
`load_config` either accept it or raise the project's `ConfigError`, never
another exception, and each example takes under 1 s (a robustness
bound, measured per example)."""

from __future__ import annotations

import copy
import math
import os
import tempfile
import time
import tomllib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from compd.config.loader import load_config, parse_config
from compd.errors import ConfigError

from .test_bad_configs import BASES

#: the bound for one config or model table
PER_EXAMPLE_S = 1.0
SETTINGS = settings(max_examples=int(os.environ.get("COMPD_FUZZ_EXAMPLES", "150")),
                    deadline=None, derandomize=os.environ.get("COMPD_FUZZ_EXAMPLES") is None,
                    suppress_health_check=[HealthCheck.too_slow])


@pytest.fixture(scope="module")
def workdir() -> Iterator[Path]:
    with tempfile.TemporaryDirectory(prefix="compd-fuzz-") as d:
        yield Path(d)


def _docs() -> dict[str, dict[str, Any]]:
    return {name: tomllib.loads(text.replace("{port}", "5020")) for name, text in BASES.items()}


DOCS = _docs()

scalars = st.one_of(
    st.booleans(), st.integers(min_value=-(2**63), max_value=2**63 - 1),
    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=30),
    st.sampled_from(["", "sp2", "degC", "modbus", "None", "/", "../x", "a\x00b", "nan",
                     "ns=2;s=X", "holding", "REAL", "-1", "1e400"]))
toml_values = st.recursive(
    scalars,
    lambda inner: st.one_of(st.lists(inner, max_size=4),
                            st.dictionaries(st.text(max_size=12), inner, max_size=4)),
    max_leaves=12)


def _paths(doc: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    out: list[tuple[Any, ...]] = []
    if isinstance(doc, dict):
        for k, v in doc.items():
            out.append((*prefix, k))
            out.extend(_paths(v, (*prefix, k)))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            out.append((*prefix, i))
            out.extend(_paths(v, (*prefix, i)))
    return out


def _parent(doc: Any, path: tuple[Any, ...]) -> Any:
    for p in path[:-1]:
        doc = doc[p]
    return doc


@st.composite
def mutated_docs(draw: st.DrawFn) -> dict[str, Any]:
    doc = copy.deepcopy(DOCS[draw(st.sampled_from(sorted(DOCS)))])
    for _ in range(draw(st.integers(min_value=1, max_value=4))):
        paths = _paths(doc)
        if not paths:
            break
        path = draw(st.sampled_from(paths))
        parent = _parent(doc, path)
        key = path[-1]
        op = draw(st.sampled_from(["drop", "replace", "retype", "add"]))
        if op == "drop":
            del parent[key]
        elif op == "replace":
            parent[key] = draw(toml_values)
        elif op == "retype":
            old = parent[key]
            parent[key] = (str(old) if not isinstance(old, str)
                           else draw(st.one_of(st.integers(), st.floats(), st.booleans())))
        elif isinstance(parent, dict):
            parent[draw(st.text(min_size=1, max_size=12))] = draw(toml_values)
        else:
            parent.append(draw(toml_values))
    return doc


def _only_config_error(fn: Any, *args: Any) -> None:
    started = time.perf_counter()
    try:
        fn(*args)
    except ConfigError as exc:
        assert isinstance(exc.key, str) and exc.reason
    elapsed_s = time.perf_counter() - started
    assert elapsed_s < PER_EXAMPLE_S, f"{elapsed_s:.3f} s for one example"


@SETTINGS
@given(doc=mutated_docs())
def test_mutated_configs_raise_only_config_error(doc: dict[str, Any], workdir: Path) -> None:
    _only_config_error(parse_config, doc, workdir / "compd.toml", b"")


@SETTINGS
@given(doc=st.dictionaries(st.text(max_size=12), toml_values, max_size=6))
def test_random_documents_raise_only_config_error(doc: dict[str, Any], workdir: Path) -> None:
    _only_config_error(parse_config, doc, workdir / "compd.toml", b"")


@SETTINGS
@given(data=st.one_of(st.binary(max_size=400), st.text(max_size=400).map(str.encode)))
def test_random_files_raise_only_config_error(data: bytes, workdir: Path) -> None:
    path = workdir / "random.toml"
    path.write_bytes(data)
    _only_config_error(load_config, path)


coefficient = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True, width=64),
    st.floats(min_value=-3.0, max_value=3.0),
    st.sampled_from(["1", "-0.99983", "0", "1e308", "nan", "x", ""]),
    st.integers(min_value=-10, max_value=10))
term = st.fixed_dictionaries(
    {"name": st.text(min_size=0, max_size=8),
     "inputs": st.dictionaries(st.sampled_from(["bearing", "ambient", "motor", "x"]),
                               st.one_of(st.floats(), st.integers(), st.text(max_size=3)),
                               max_size=3),
     "a": st.lists(coefficient, max_size=6),
     "b": st.lists(coefficient, max_size=6)},
    optional={"kind": st.sampled_from(["tf", "greybox", "mbotv", "poly", "?"]),
              "offset": coefficient})


@SETTINGS
# found by this fuzzer: 1e308 / 0.5 overflows when the denominator is normalised
@example(terms=[{"name": "0", "inputs": {"bearing": 0.0}, "a": [1.0], "b": [0.5, "1e308"]}],
         period=None)
@given(terms=st.lists(term, min_size=0, max_size=4),
       period=st.one_of(st.none(), st.floats(), st.integers(min_value=-2, max_value=5)))
def test_random_model_tables_raise_only_config_error(terms: list[dict[str, Any]],
                                                     period: float | None,
                                                     workdir: Path) -> None:
    doc = copy.deepcopy(DOCS["modbus"])
    doc["model"] = {"terms": terms}
    if period is not None:
        doc["model"]["period_s"] = period
    _only_config_error(parse_config, doc, workdir / "compd.toml", b"")


def test_the_unmutated_bases_load(workdir: Path) -> None:
    for doc in DOCS.values():
        cfg = parse_config(copy.deepcopy(doc), workdir / "compd.toml", b"")
        assert math.isfinite(cfg.period_s)
