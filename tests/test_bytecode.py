"""A run started with PYTHONDONTWRITEBYTECODE compiles each module once: the
bytecode goes to a directory of the run's own (tests/conftest.py), which the
processes the run starts read, and which is gone after the run."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_PROBE = """
import json, os, subprocess, sys
from tests.conftest import pytest_configure

class Config:
    cleanups = []
    def add_cleanup(self, fn):
        self.cleanups.append(fn)

config = Config()
pytest_configure(config)
prefix = os.environ["PYTHONPYCACHEPREFIX"]
subprocess.run([sys.executable, "-c", "import compd.sysexits"], check=True)
compiled = sorted(f for _, _, files in os.walk(prefix) for f in files if "sysexits" in f)
for fn in config.cleanups:
    fn()
print(json.dumps({"compiled": compiled, "left": os.path.exists(prefix),
                  "env": os.environ.get("PYTHONDONTWRITEBYTECODE"),
                  "prefix": os.environ.get("PYTHONPYCACHEPREFIX")}))
"""


def test_a_run_that_writes_no_bytecode_compiles_once_outside_the_tree() -> None:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPYCACHEPREFIX"}
    env["PYTHONDONTWRITEBYTECODE"] = "1"
    proc = subprocess.run([sys.executable, "-c", _PROBE], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 0, proc.stderr
    seen = json.loads(proc.stdout.strip().splitlines()[-1])
    assert seen["compiled"] == [f"sysexits.{sys.implementation.cache_tag}.pyc"]
    assert seen == {**seen, "left": False, "env": "1", "prefix": None}
