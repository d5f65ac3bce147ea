"""`compd check` warns (exit 0, one line on stderr, and in --json) when one
count of an integer offset address is more than the slew limit allows per
period (an int16 ×10 µm encoding would chatter at run time); a fine or float
encoding gets no warning."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.configs import Toml, write_config

ROOT = Path(__file__).resolve().parents[3]

COARSE = '{ unit = 1, kind = "holding", address = 20, type = "int16", scale = 10.0 }'


def _config(tmp_path: Path, offset: str, limit_um: float = 200.0) -> Path:
    return write_config(tmp_path, base="modbus", filename="modbus.toml", offset=Toml(offset),
                        limit_um=limit_um, slew_um_s=0.1)


def _check(path: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "compd", "check", str(path), *extra],
                          check=False, cwd=ROOT, capture_output=True, text=True, timeout=60)


def test_a_count_coarser_than_the_slew_step_is_warned_of(tmp_path: Path) -> None:
    r = _check(_config(tmp_path, COARSE))
    assert r.returncode == 0, r.stderr
    [line] = r.stderr.strip().splitlines()
    assert line.startswith("compd check: warning: output.offset: one count")
    assert "10 µm" in line and "0.1 µm/s × 60 s = 6 µm" in line
    assert "at most one count per cycle" in line and "whole count" in line
    assert "one count 10 µm" in r.stdout  # the output stage line


def test_the_warning_in_json(tmp_path: Path) -> None:
    r = _check(_config(tmp_path, COARSE), "--json")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert doc["output"]["count_um"] == 10.0
    [w] = doc["warnings"]
    assert w.startswith("output.offset: one count") and "10 µm" in w


def test_a_count_beyond_the_limit_says_only_zero(tmp_path: Path) -> None:
    r = _check(_config(tmp_path, COARSE, limit_um=8.0))
    assert r.returncode == 0, r.stderr
    assert "the only offset it can hold within the limit is 0" in r.stderr


@pytest.mark.parametrize("offset", [
    '{ unit = 1, kind = "holding", address = 0, type = "float32" }',
    '{ unit = 1, kind = "holding", address = 20, type = "int16", scale = 0.01 }',
], ids=["float32", "int16_centi"])
def test_no_warning_for_a_fine_or_float_encoding(tmp_path: Path, offset: str) -> None:
    r = _check(_config(tmp_path, offset), "--json")
    assert r.returncode == 0, r.stderr
    assert r.stderr == ""
    assert json.loads(r.stdout)["warnings"] == []
