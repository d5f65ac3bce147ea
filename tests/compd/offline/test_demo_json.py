"""`compd demo --json` prints only its JSON object on stdout (the human lines
go to stderr), so `compd demo --json | python -m json.tool` works, as with
`fit --json` and `replay --json`."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]


def test_demo_json_stdout_is_one_json_object() -> None:
    r = subprocess.run([sys.executable, "-m", "compd", "demo", "--json", "--protocol", "modbus",
                        "--hours", "0.25", "--seconds", "1"], cwd=ROOT, capture_output=True,
                       text=True, timeout=180, check=False)
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)  # nothing else on stdout
    assert isinstance(doc, dict) and "range_reduction" in doc
    assert "compd demo:" in r.stderr and "range reduction" in r.stderr
