"""deploy/systemd/compd@.service: the template for several machines on one PC.
Each instance has its own config, state and credentials, and exactly the
sandbox of compd.service (whose settings tests/deploy/test_systemd_unit.py
checks one by one); systemd's analyser accepts an instance of it and rates it
as it rates compd.service."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from .test_systemd_unit import ANALYZE, MAX_EXPOSURE, UNIT, needs_analyze, parse_unit

TEMPLATE = UNIT.parent / "compd@.service"
#: what differs per instance; every other key of the unit is the same
PER_INSTANCE = {
    "ExecStart": ["/usr/local/bin/compd run /etc/compd/%i.toml"],
    "StateDirectory": ["compd/%i"],
    "LoadCredential": ["controller-password:/etc/compd/credentials/%i/controller-password"],
}


def test_template_differs_from_the_unit_only_per_instance() -> None:
    unit, template = parse_unit(UNIT.read_text()), parse_unit(TEMPLATE.read_text())
    assert template.keys() == unit.keys()
    for section in unit:
        differing = {k for k in unit[section].keys() | template[section].keys()
                     if unit[section].get(k) != template[section].get(k)}
        if section == "Service":
            assert differing == PER_INSTANCE.keys()
            assert {k: template[section][k] for k in PER_INSTANCE} == PER_INSTANCE
        elif section == "Unit":
            assert differing == {"Description"}
            assert template[section]["Description"][0].endswith(" for %i")
        else:
            assert differing == set(), section


def _instance(tmp_path: Path, name: str = "mill-1") -> Path:
    """An instance of the template (compd@NAME.service), ExecStart pointing at
    this venv's compd (verify checks that the executable exists)."""
    compd = Path(sys.executable).parent / "compd"
    text, n = re.subn(r"^ExecStart=/usr/local/bin/compd ", f"ExecStart={compd} ",
                      TEMPLATE.read_text(), flags=re.MULTILINE)
    assert n == 1
    out = tmp_path / f"compd@{name}.service"
    out.write_text(text)
    return out


@needs_analyze
def test_systemd_analyze_verify_accepts_an_instance(tmp_path: Path) -> None:
    assert ANALYZE is not None
    unit = _instance(tmp_path)
    proc = subprocess.run([ANALYZE, "verify", str(unit)], capture_output=True, text=True,
                          timeout=60, check=False)
    complaints = [line for line in (proc.stdout + proc.stderr).splitlines()
                  if unit.name in line or str(unit) in line]
    assert proc.returncode == 0, proc.stderr
    assert complaints == []


@needs_analyze
def test_instance_security_exposure_is_ok_or_better(tmp_path: Path) -> None:
    assert ANALYZE is not None
    unit = _instance(tmp_path)
    proc = subprocess.run([ANALYZE, "security", "--offline=yes", str(unit)],
                          capture_output=True, text=True, timeout=60, check=False)
    match = re.search(r"Overall exposure level for \S+: (\d+\.\d+) (\w+)", proc.stdout)
    if match is None:
        if "--offline" in proc.stderr or "unrecognized option" in proc.stderr:
            pytest.skip(f"systemd-analyze too old for --offline: {proc.stderr.strip()}")
        pytest.fail(f"no exposure level in the output:\n{proc.stdout}\n{proc.stderr}")
    score, level = float(match.group(1)), match.group(2)
    print(f"\nsystemd-analyze security --offline=yes {unit.name}: {score} {level}")
    assert score <= MAX_EXPOSURE, proc.stdout
    assert level in {"SAFE", "OK"}
