"""Config check: an output address whose encoding cannot hold what compd
writes is refused: Int16 at 0.0001 units/µm holds ±3.28 µm,
not the ±200 µm of limit_um, and every write would fail at run time."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from compd.config.loader import load_config
from compd.config.output_range import HEARTBEAT_MAX, STATUS_MAX
from compd.core.cycle import HEARTBEAT_MODULO
from compd.core.output import Status
from compd.errors import ConfigError
from tests.configs import Toml, write_config

ROOT = Path(__file__).resolve().parents[3]


def _config(tmp_path: Path, protocol: str, offset: str, limit_um: float = 200.0,
            extra: str = "") -> Path:
    return write_config(tmp_path, base=protocol, filename=f"{protocol}.toml",
                        offset=Toml(offset), limit_um=limit_um,
                        swap=[('\nunit = "um"\n', f'\nunit = "um"\n{extra}')])


REFUSED = [
    ("modbus", '{ kind = "holding", address = 0, type = "int16", scale = 0.0001 }',
     "-3.2768..3.2767 µm", "-200..200 µm"),
    ("modbus", '{ kind = "holding", address = 0, type = "uint16" }', "0..65535 µm",
     "-200..200 µm"),
    ("modbus", '{ kind = "holding", address = 0, type = "int32", scale = 1e-9 }',
     "-2.14748..2.14748 µm", "-200..200 µm"),
    ("modbus", '{ kind = "holding", address = 0, type = "float32", scale = 1e-37 }',
     "-34.0282..34.0282 µm", "-200..200 µm"),
    ("s7", '{ db = 2, offset = 0, type = "INT", scale = 0.001 }', "-32.768..32.767 µm",
     "-200..200 µm"),
    ("s7", '{ db = 2, offset = 0, type = "WORD" }', "0..65535 µm", "-200..200 µm"),
    ("s7", '{ db = 2, offset = 0, type = "DINT", scale = 1e-8 }', "-21.4748..21.4748 µm",
     "-200..200 µm"),
    ("s7", '{ db = 2, offset = 0, type = "REAL", scale = 1e-37 }', "-34.0282..34.0282 µm",
     "-200..200 µm"),
    ("focas", '{ kind = "pmc", area = "D", address = 100, type = "byte" }', "-128..127 µm",
     "-200..200 µm"),
    ("focas", '{ kind = "pmc", area = "D", address = 100, type = "word", scale = 0.01 }',
     "-327.68..327.67 µm", "-400..400 µm"),
    ("focas", '{ kind = "pmc", area = "D", address = 100, type = "long", scale = 1e-8 }',
     "-21.4748..21.4748 µm", "-200..200 µm"),
    ("focas", '{ kind = "pmc", area = "D", address = 100, type = "float", scale = 1e-37 }',
     "-34.0282..34.0282 µm", "-200..200 µm"),
]


@pytest.mark.parametrize(("protocol", "offset", "holds", "needs"), REFUSED)
def test_offset_encoding_that_cannot_hold_the_limit_is_refused(
        tmp_path: Path, protocol: str, offset: str, holds: str, needs: str) -> None:
    limit = 400.0 if "400" in needs else 200.0
    with pytest.raises(ConfigError) as err:
        load_config(_config(tmp_path, protocol, offset, limit))
    assert err.value.key == "output.offset"
    assert holds in str(err.value) and needs in str(err.value), str(err.value)


@pytest.mark.parametrize(("protocol", "offset", "limit"), [
    ("modbus", '{ kind = "holding", address = 0, type = "int16", scale = 0.01 }', 327.67),
    ("s7", '{ db = 2, offset = 0, type = "INT", scale = 0.01 }', 200.0),
    ("focas", '{ kind = "pmc", area = "D", address = 100, type = "word", scale = 0.01 }',
     300.0),
    # a double is 8 bytes: at D100 it would run into the heartbeat at D104
    ("focas", '{ kind = "pmc", area = "D", address = 200, type = "double", scale = 1e-300 }',
     200.0),
])
def test_offset_encoding_that_holds_the_limit_is_accepted(
        tmp_path: Path, protocol: str, offset: str, limit: float) -> None:
    load_config(_config(tmp_path, protocol, offset, limit))


def test_unit_and_sign_count_in_the_range(tmp_path: Path) -> None:
    # mm on the controller: int16 at 0.0001 mm per count holds ±3.2767 mm
    offset = '{ kind = "holding", address = 0, type = "int16", scale = 0.0001 }'
    load_config(_config(tmp_path, "modbus", offset, 3000.0, extra='scale = 0.001\n'))
    with pytest.raises(ConfigError, match=r"output\.offset"):
        load_config(_config(tmp_path, "modbus", offset, 4000.0, extra='scale = 0.001\n'))


def test_status_word_in_a_byte_is_refused(tmp_path: Path) -> None:
    p = _config(tmp_path, "focas", '{ kind = "pmc", area = "D", address = 100, type = "long",'
                                    ' scale = 0.1 }')
    p.write_text(p.read_text().replace('status = { kind = "pmc", area = "D", address = 108, '
                                       'type = "word" }',
                                       'status = { kind = "pmc", area = "D", address = 108, '
                                       'type = "byte" }'))
    with pytest.raises(ConfigError) as err:
        load_config(p)
    assert err.value.key == "output.status" and "0..32767" in str(err.value)


def test_compd_check_exits_78_naming_the_key_and_both_ranges(tmp_path: Path) -> None:
    p = _config(tmp_path, "modbus", '{ kind = "holding", address = 0, type = "int16", '
                                    'scale = 0.0001 }')
    r = subprocess.run([sys.executable, "-m", "compd", "check", str(p)], check=False, cwd=ROOT,
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 78, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "output.offset" in lines[0]
    assert "-3.2768..3.2767 µm" in lines[0] and "-200..200 µm" in lines[0]


def test_the_config_knows_the_heartbeat_and_status_ranges_of_the_core() -> None:
    assert HEARTBEAT_MAX == HEARTBEAT_MODULO - 1
    assert int(~Status(0)) == STATUS_MAX
