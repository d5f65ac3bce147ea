"""Config check: no written address may share controller memory with another,
checked by `compd check` as by the HIL drive map: a float32 offset at holding
registers 0-1 with the heartbeat at holding register 1 would overwrite half the
offset every cycle."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from compd.cli import main
from compd.config.loader import load_config
from compd.errors import ConfigError
from compd.sysexits import EX_CONFIG
from tests.configs import write_config
from tests.shipped import EXAMPLES

ROOT = Path(__file__).resolve().parents[3]

ADAPTATION = """
[adaptation]
enabled = true
mode = "apply"
probe_value = {probe_value}
probe_counter = {probe_counter}
"""


def _config(tmp_path: Path, protocol: str, *changes: tuple[str, str], extra: str = "") -> Path:
    """The shipped example of `protocol` with each (old line, new line) swapped in."""
    return write_config(tmp_path, base=protocol, filename=f"{protocol}.toml", swap=changes,
                        extra=extra)


MB_HEARTBEAT = 'heartbeat = { unit = 1, kind = "holding", address = 2, type = "uint16" }'
MB_STATUS = 'status = { unit = 1, kind = "holding", address = 3, type = "uint16" }'
MB_BEARING = 'address = { unit = 1, kind = "input", address = 0, type = "int16", scale = 0.1 }'
MB_MOTOR = 'address = { unit = 1, kind = "input", address = 1, type = "int16", scale = 0.1 }'
S7_OFFSET = 'offset = { db = 2, offset = 0, type = "REAL" }'
S7_HEARTBEAT = 'heartbeat = { db = 2, offset = 4, type = "DINT" }'
S7_COLUMN = 'address = { db = 1, offset = 4, type = "INT", scale = 0.1 }'
PMC_HEARTBEAT = 'heartbeat = { kind = "pmc", area = "D", address = 104, type = "long" }'
PMC_STATUS = 'status = { kind = "pmc", area = "D", address = 108, type = "word" }'
UA_STATUS = 'status = { node = "ns=2;s=Machine.status" }'
HAL_STATUS = 'status = { pin = "status", net = "compd-status", type = "s32" }'
HAL_MOTOR = 'address = { pin = "motor", net = "compd-motor" }'
HAL_MACHINE_ON = 'machine_on = { kind = "get", hal = "motion.motion-enabled" }'


def test_compd_check_refuses_the_issue_case_naming_both_keys_and_the_register(
        tmp_path: Path) -> None:
    p = _config(tmp_path, "modbus", (MB_HEARTBEAT, MB_HEARTBEAT.replace("= 2,", "= 1,")))
    r = subprocess.run([sys.executable, "-m", "compd", "check", str(p)], check=False,
                       cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 78, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert "output.heartbeat" in lines[0] and "output.offset" in lines[0]
    assert "holding register 1 of unit 1" in lines[0]
    assert "Traceback" not in r.stderr
    # docs/operation.md quotes this very line
    assert lines[0] in (ROOT / "docs" / "operation.md").read_text(encoding="utf-8")


REFUSED = [
    # Modbus: the status word on the heartbeat; a channel reading the offset
    ("modbus", [(MB_STATUS, MB_STATUS.replace("= 3,", "= 2,"))], "output.status",
     "output.heartbeat", "holding register 2 of unit 1"),
    ("modbus", [(MB_BEARING, 'address = { unit = 1, kind = "holding", address = 1, '
                             'type = "int16" }')],
     "channels.bearing.address", "output.offset", "holding register 1 of unit 1"),
    # two reads of different values sharing a register: one decodes the other's half
    ("modbus", [(MB_BEARING, MB_BEARING.replace('"int16", scale = 0.1', '"float32"'))],
     "channels.motor.address", "channels.bearing.address", "input register 1 of unit 1"),
    # S7: a REAL offset 0-3 and a DINT heartbeat 3-6 share one byte
    ("s7", [(S7_HEARTBEAT, S7_HEARTBEAT.replace("offset = 4", "offset = 3"))],
     "output.heartbeat", "output.offset", "DB2 byte 3"),
    ("s7", [(S7_COLUMN, 'address = { db = 2, offset = 2, type = "INT" }')],
     "channels.column.address", "output.offset", "DB2 bytes 2..3"),
    # FOCAS: a PMC word status inside the long heartbeat
    ("focas", [(PMC_STATUS, PMC_STATUS.replace("108", "106"))], "output.status",
     "output.heartbeat", "PMC D106..107"),
    # OPC UA: the same node, spelt twice
    ("opcua", [(UA_STATUS, 'status = { node = "ns=2;s=Machine.heartbeat" }')],
     "output.status", "output.heartbeat", "node ns=2;s=Machine.heartbeat"),
    # LinuxCNC: two outputs driving one HAL signal (HAL allows one writer)
    ("linuxcnc", [(HAL_STATUS, HAL_STATUS.replace("compd-status", "compd-heartbeat"))],
     "output.status", "output.heartbeat", "HAL signal compd-heartbeat"),
    # one pin name for two outputs (on other signals): compd's component has it once
    ("linuxcnc", [(HAL_STATUS, HAL_STATUS.replace('pin = "status"', 'pin = "heartbeat"'))],
     "output.status", "output.heartbeat", "HAL pin heartbeat"),
    # a channel reading the signal compd's offset counts drive; a state read of it
    ("linuxcnc", [(HAL_MOTOR, 'address = { pin = "motor", net = "compd-eoffset-counts" }')],
     "channels.motor.address", "output.offset", "HAL signal compd-eoffset-counts"),
    ("linuxcnc", [(HAL_MACHINE_ON, 'machine_on = { kind = "get", hal = "compd-status" }')],
     "output.machine_on", "output.status", "HAL signal compd-status"),
]


@pytest.mark.parametrize(("protocol", "changes", "key", "other", "cells"), REFUSED)
def test_overlapping_addresses_are_refused_naming_both_keys_and_the_cells(
        tmp_path: Path, protocol: str, changes: list[tuple[str, str]], key: str, other: str,
        cells: str) -> None:
    with pytest.raises(ConfigError) as err:
        load_config(_config(tmp_path, protocol, *changes))
    assert err.value.key == key
    assert other in err.value.reason and cells in err.value.reason


ACCEPTED = [
    # as shipped: edge-adjacent outputs (float32 offset 0-1, heartbeat 2, status 3)
    ("modbus", []),
    # the same register in the other table (input 0 vs holding 0) and another unit
    ("modbus", [(MB_HEARTBEAT, 'heartbeat = { unit = 2, kind = "holding", address = 1, '
                               'type = "uint16" }')]),
    # one sensor read under two channel names (any scale): the same value
    ("modbus", [(MB_MOTOR, MB_BEARING.replace("scale = 0.1", "scale = 1.0"))]),
    # S7: REAL 0-3, DINT 4-7 (edge-adjacent); FOCAS: long 100-103, long 104-107
    ("s7", []),
    ("s7", [(S7_OFFSET, S7_OFFSET.replace("db = 2", "db = 3"))]),
    ("focas", []),
    ("focas", [(PMC_HEARTBEAT, PMC_HEARTBEAT.replace('area = "D"', 'area = "R"')
                .replace("104", "100"))]),
    ("opcua", []),
    ("linuxcnc", []),
    # one HAL signal read by two of compd's pins: one value
    ("linuxcnc", [(HAL_MOTOR, 'address = { pin = "motor", net = "compd-bearing" }')]),
]


@pytest.mark.parametrize(("protocol", "changes"), ACCEPTED)
def test_adjacent_or_separate_addresses_and_identical_reads_are_accepted(
        tmp_path: Path, protocol: str, changes: list[tuple[str, str]]) -> None:
    load_config(_config(tmp_path, protocol, *changes))


def test_the_probe_addresses_are_checked_too(tmp_path: Path) -> None:
    extra = ADAPTATION.format(
        probe_value='{ kind = "holding", address = 3, type = "float32" }',
        probe_counter='{ kind = "input", address = 14, type = "uint16" }')
    with pytest.raises(ConfigError) as err:
        load_config(_config(tmp_path, "modbus", extra=extra))
    assert err.value.key == "adaptation.probe_value"
    assert "output.status" in err.value.reason
    assert "holding register 3 of unit 1" in err.value.reason
    fine = ADAPTATION.format(
        probe_value='{ kind = "holding", address = 4, type = "float32" }',
        probe_counter='{ kind = "input", address = 14, type = "uint16" }')
    assert set(load_config(_config(tmp_path, "modbus", extra=fine)).probes) == {
        "probe_value", "probe_counter"}


# -- compd run DIR: machines that name one controller ----------------------------

def _twin(tmp_path: Path, endpoint_b: str, *changes_b: tuple[str, str]) -> Path:
    """Two Modbus machines in one directory: the shipped example, and a second
    one with its own name and state at `endpoint_b`."""
    d = tmp_path / "machines"
    d.mkdir()
    text = (EXAMPLES / "modbus.toml").read_text(encoding="utf-8")
    (d / "a.toml").write_text(text, encoding="utf-8")
    b = (text.replace('name = "sim-modbus"', 'name = "twin"')
         .replace('dir = "state-modbus"', 'dir = "state-twin"')
         .replace('endpoint = "modbus://127.0.0.1:5020"', f'endpoint = "{endpoint_b}"'))
    for old, new in changes_b:
        assert b.count(old) == 1, old
        b = b.replace(old, new)
    (d / "b.toml").write_text(b, encoding="utf-8")
    return d


def test_two_machines_writing_one_controllers_registers_are_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # the same controller, spelt differently (the default port, no scheme)
    d = _twin(tmp_path, "127.0.0.1:5020")
    for command in ("check", "run"):
        assert main([command, str(d)]) == EX_CONFIG
        [line] = capsys.readouterr().err.strip().splitlines()
        assert f"{d / 'b.toml'}: output.offset overlaps {d / 'a.toml'}: output.offset" in line
        assert "holding registers 0..1 of unit 1" in line and "127.0.0.1:5020" in line


@pytest.mark.parametrize(("endpoint_b", "changes_b"), [
    ("modbus://127.0.0.1:5021", []),  # another controller: the same addresses are fine
    ("modbus://127.0.0.1:5020", [     # one controller, the twin's outputs further on
        ('offset = { unit = 1, kind = "holding", address = 0, type = "float32" }',
         'offset = { unit = 1, kind = "holding", address = 10, type = "float32" }'),
        (MB_HEARTBEAT, MB_HEARTBEAT.replace("= 2,", "= 12,")),
        (MB_STATUS, MB_STATUS.replace("= 3,", "= 13,"))]),
])
def test_machines_apart_or_on_separate_registers_are_accepted(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], endpoint_b: str,
        changes_b: list[tuple[str, str]]) -> None:
    # both read the same sensors (input registers 0..5): reads of one value may coincide
    assert main(["check", str(_twin(tmp_path, endpoint_b, *changes_b))]) == 0, \
        capsys.readouterr().err
