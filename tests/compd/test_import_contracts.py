"""Every module of compd is placed by the import contracts (a module outside
them could import anything)."""

from __future__ import annotations

import tomllib
from pathlib import Path

from tests.shipped import PACKAGES_ROOT

ROOT = Path(__file__).resolve().parents[2]
#: in no layer on purpose: the package's docstring, and the test doubles (their own contract)
UNLAYERED = {"compd", "compd.testing"}


def _contracts() -> list[dict[str, object]]:
    doc = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    contracts: list[dict[str, object]] = doc["tool"]["importlinter"]["contracts"]
    return contracts


def _layered() -> set[str]:
    out: set[str] = set()
    for contract in _contracts():
        if contract["type"] != "layers":
            continue
        layers = contract["layers"]
        assert isinstance(layers, list)
        for layer in layers:
            out.update(m.strip() for m in str(layer).split("|"))
    return out


def _compd_modules() -> set[str]:
    """compd's top-level modules and sub-packages (the rooms)."""
    pkg = PACKAGES_ROOT / "compd"
    files = {f"compd.{p.stem}" for p in pkg.glob("*.py") if p.stem != "__init__"}
    rooms = {f"compd.{p.parent.name}" for p in pkg.glob("*/__init__.py")}
    return files | rooms | {"compd"}


def test_every_compd_module_is_in_a_layer() -> None:
    loose = _compd_modules() - _layered() - UNLAYERED
    assert not loose, f"modules outside every layers contract: {sorted(loose)}"


def test_nothing_the_daemon_runs_may_import_the_test_doubles() -> None:
    (testing,) = [c for c in _contracts() if c.get("forbidden_modules") == ["compd.testing"]]
    sources = testing["source_modules"]
    assert isinstance(sources, list)
    assert set(sources) == _compd_modules() - UNLAYERED
