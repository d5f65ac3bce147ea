"""A run started with PYTHONDONTWRITEBYTECODE compiles each module of the
project once (tests/conftest.py): the processes the run starts write and read
bytecode beside the sources, and the ``__pycache__`` folders the run made are
gone after it; those it found stay."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import compd

ROOT = Path(__file__).resolve().parents[1]

_PROBE = """
import json, os, subprocess, sys
from pathlib import Path
from tests.conftest import pytest_configure

class Config:
    cleanups = []
    def add_cleanup(self, fn):
        self.cleanups.append(fn)

config = Config()
pytest_configure(config)
subprocess.run([sys.executable, "-c", "import compd.sysexits, models.kept"], check=True)
made = sorted(str(p) for p in Path().rglob("*.pyc"))
for fn in config.cleanups:
    fn()
print(json.dumps({"made": made, "left": sorted(str(p) for p in Path().rglob("*.pyc")),
                  "env": os.environ.get("PYTHONDONTWRITEBYTECODE")}))
"""


def test_a_run_that_writes_no_bytecode_compiles_once_and_leaves_the_tree_as_it_was(
        tmp_path: Path) -> None:
    tag = sys.implementation.cache_tag
    # the package's files from wherever it is imported from (the checkout, or the
    # installed wheel, whose test run has no compd/ in its tree)
    package = Path(compd.__file__).resolve().parent
    for name, src in (("tests/__init__.py", ROOT / "tests" / "__init__.py"),
                      ("tests/conftest.py", ROOT / "tests" / "conftest.py"),
                      ("compd/__init__.py", package / "__init__.py"),
                      ("compd/sysexits.py", package / "sysexits.py")):
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(src, tmp_path / name)
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "__init__.py").write_text("")
    (tmp_path / "models" / "kept.py").write_text("")
    (tmp_path / "models" / "__pycache__").mkdir()  # the user's: stays
    (tmp_path / "models" / "__pycache__" / f"__init__.{tag}.pyc").write_bytes(b"")
    env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1"}
    proc = subprocess.run([sys.executable, "-c", _PROBE], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 0, proc.stderr
    seen = json.loads(proc.stdout.strip().splitlines()[-1])
    assert f"compd/__pycache__/sysexits.{tag}.pyc" in seen["made"]
    assert f"models/__pycache__/kept.{tag}.pyc" in seen["made"]
    assert seen["left"] == [f"models/__pycache__/__init__.{tag}.pyc",
                            f"models/__pycache__/kept.{tag}.pyc"]
    assert seen["env"] == "1"


def test_the_controller_writes_the_bytecode_the_workers_read(
        pytestconfig: pytest.Config, tmp_path: Path) -> None:
    """Before xdist's workers start, the test modules' rewritten bytecode (pytest's
    own cache file) and every other module's plain bytecode are on disk."""
    from _pytest.assertion.rewrite import PYC_TAIL

    from tests.conftest import _warm_bytecode

    for top in ("compd", "drivers", "models", "tests"):
        (tmp_path / top).mkdir()
        (tmp_path / top / "helper.py").write_text("X = 1\n")
    (tmp_path / "tests" / "test_x.py").write_text("def test_x() -> None:\n    assert 1 == 1\n")
    (tmp_path / "tests" / "conftest.py").write_text("Y = 2\n")
    _warm_bytecode(pytestconfig, tmp_path)
    tag = sys.implementation.cache_tag
    for top in ("compd", "drivers", "models", "tests"):
        assert (tmp_path / top / "__pycache__" / f"helper.{tag}.pyc").is_file()
    cache = tmp_path / "tests" / "__pycache__"
    assert (cache / f"test_x{PYC_TAIL}").is_file() and (cache / f"conftest{PYC_TAIL}").is_file()
    # a test module is only ever imported through the rewriting hook
    assert not (cache / f"test_x.{tag}.pyc").exists()
