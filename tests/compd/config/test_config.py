"""Config validation: every refusal names the key path; check and run exit 78."""

from __future__ import annotations

from pathlib import Path

import pytest

from compd.cli import main
from compd.config.loader import load_config
from compd.config.schema import DEFAULT_STUCK_DELTA_K
from compd.core.cycle import params_from_config
from compd.errors import EX_CONFIG, ConfigError
from tests.configs import MINIMAL, write_config
from tests.shipped import EXAMPLES, LIBRARY


def _error(tmp_path: Path, text: str) -> ConfigError:
    with pytest.raises(ConfigError) as info:
        load_config(write_config(tmp_path, base=text))
    return info.value


def test_base_config_loads(tmp_path: Path) -> None:
    cfg = load_config(write_config(tmp_path, base=MINIMAL))
    assert set(cfg.channels) == {"bearing", "ambient"}
    assert cfg.model.name == "SP2 per-spindle"
    assert cfg.state_dir == tmp_path / "state"
    assert cfg.recorder_path == tmp_path / "state" / "samples.sqlite"


@pytest.mark.parametrize(("change", "key", "words"), [
    (('range = [-20.0, 150.0]', 'range = [150.0, -20.0]'), "channels.bearing.range",
     "lower bound must be below upper bound"),
    (('limit_um = 100.0', 'limit_um = 0'), "output.limit_um", "greater than 0"),
    (('slew_um_s = 1.0', 'slew_um_s = 1.0\nbogus = 3'), "output.bogus", "unknown key"),
    (('period_s = 1.0', 'period_s = "fast"'), "machine.period_s", "number"),
    (('unit = "degC"\nrange = [-20.0', 'unit = "furlong"\nrange = [-20.0'),
     "channels.bearing.unit", "unknown unit"),
    (('timeout_s = 0.2', 'timeout_s = 0.7'), "controller.timeout_s", "half"),
    (('address = { kind = "input", address = 0, type = "int16", scale = 0.1 }',
      'address = { node = "ns=2;s=Machine.bearing" }'),
     "channels.bearing.address", "opcua address"),
    (('address = { kind = "input", address = 0, type = "int16", scale = 0.1 }',
      'address = { kind = "input", address = 70000, type = "int16" }'),
     "channels.bearing.address.address", "less than or equal"),
    (('file = "sp2"', 'file = "nonexistent.toml"'), "model.file", "no model file"),
    (('[channels.ambient]', '[channels.ambient_x]'), "model.file", "unknown channel"),
    (('name = "m"\nperiod_s = 1.0', 'name = "m"\nperiod_s = 2.0'), "model.file",
     "period_s"),
    (('protocol = "modbus"', 'protocol = "profibus"'), "controller.protocol", "opcua"),
    (('unit = "degC"\nrange = [-10.0, 60.0]',
      'unit = "rpm"\nrange = [-10.0, 60.0]\nstuck_delta_k = 2.0'),
     "channels.ambient.stuck_delta_k", "temperature channels only"),
    (('range = [-10.0, 60.0]', 'range = [-10.0, 60.0]\nstuck_delta_k = 0.0'),
     "channels.ambient.stuck_delta_k", "greater than 0"),
    # a reconnect only every 30 s: compensation could not resume within 10 s + 2·Ts
    (('timeout_s = 0.2', 'timeout_s = 0.2\nbackoff = { initial_s = 0.1, cap_s = 30.0 }'),
     "controller.backoff.cap_s", "resume within 10 s + 2 periods"),
    (('timeout_s = 0.2', 'timeout_s = 0.2\nbackoff = { initial_s = 10.5, cap_s = 10.5 }'),
     "controller.backoff.cap_s", "at most 10 s"),
    (('timeout_s = 0.2', 'timeout_s = 0.2\nbackoff = { initial_s = 5.0, cap_s = 1.0 }'),
     "controller.backoff", "cap_s (1 s) must be >= initial_s (5 s)"),
])
def test_refusals_name_the_key(tmp_path: Path, change: tuple[str, str], key: str,
                               words: str) -> None:
    old, new = change
    assert old in MINIMAL
    text = MINIMAL.replace(old, new, 1)
    err = _error(tmp_path, text)
    assert err.key == key, str(err)
    assert words.lower() in err.reason.lower(), str(err)


def test_backoff_cap_of_10_s_is_accepted(tmp_path: Path) -> None:
    text = MINIMAL.replace('timeout_s = 0.2',
                        'timeout_s = 0.2\nbackoff = { initial_s = 10.0, cap_s = 10.0 }')
    assert load_config(write_config(tmp_path, base=text)).raw.controller.backoff.cap_s == 10.0


def test_stuck_delta_k_default_explicit_and_off(tmp_path: Path) -> None:
    """A temperature channel with stuck_after_s gets the heat criterion at
    2 K unless it says otherwise (inf: off); without stuck_after_s, only when
    given."""
    def limits(bearing: str, ambient: str) -> tuple[float | None, float | None]:
        text = MINIMAL.replace('range = [-20.0, 150.0]', 'range = [-20.0, 150.0]\n' + bearing)
        text = text.replace('range = [-10.0, 60.0]', 'range = [-10.0, 60.0]\n' + ambient)
        ch = params_from_config(load_config(write_config(tmp_path, base=text))).channels
        assert ch["bearing"].temperature and ch["ambient"].temperature
        return ch["bearing"].stuck_delta_k, ch["ambient"].stuck_delta_k

    assert limits("stuck_after_s = 900.0", "") == (DEFAULT_STUCK_DELTA_K, None)
    assert DEFAULT_STUCK_DELTA_K == 2.0
    assert limits("stuck_after_s = 900.0\nstuck_delta_k = 3", "stuck_delta_k = 1.5") == \
        (3.0, 1.5)
    assert limits("stuck_after_s = 900.0\nstuck_delta_k = inf", "") == (None, None)


def test_unstable_inline_model_is_refused_naming_the_term(tmp_path: Path) -> None:
    text = MINIMAL.replace('file = "sp2"', """
[[model.terms]]
name = "runaway"
inputs = { bearing = 1.0 }
a = ["1.0"]
b = ["1", "-1.5"]
""")
    err = _error(tmp_path, text)
    assert err.key == "model.terms"
    assert "runaway" in err.reason and "unstable" in err.reason


def test_inline_model_terms_load(tmp_path: Path) -> None:
    text = MINIMAL.replace('file = "sp2"', """
[[model.terms]]
name = "spindle"
inputs = { bearing = 1.0 }
a = ["16.0005", "-15.9975", "0"]
b = ["1", "-0.99983", "0", "0"]
""")
    cfg = load_config(write_config(tmp_path, base=text))
    assert [t.name for t in cfg.model.terms] == ["spindle"]
    assert cfg.model.period_s == 1.0


def test_model_file_relative_to_the_config(tmp_path: Path) -> None:
    (tmp_path / "models").mkdir()
    src = LIBRARY / "sp2.toml"
    (tmp_path / "models" / "mine.toml").write_text(src.read_text())
    cfg = load_config(write_config(tmp_path, base=MINIMAL.replace('file = "sp2"',
                                                    'file = "models/mine.toml"')))
    assert cfg.model.name == "SP2 per-spindle"


OPCUA = """
[machine]
period_s = 1.0

[controller]
protocol = "opcua"
endpoint = "opc.tcp://127.0.0.1:4840"
timeout_s = 0.2

[controller.security]
{security}

[channels.bearing]
address = {{ node = "ns=2;s=Machine.bearing" }}
unit = "degC"
range = [-20.0, 150.0]

[channels.ambient]
address = {{ node = "ns=2;s=Machine.ambient" }}
unit = "degC"
range = [-10.0, 60.0]

[model]
file = "sp2"

[output]
offset = {{ node = "ns=2;s=Machine.offset" }}
limit_um = 100.0
slew_um_s = 1.0
"""


@pytest.mark.parametrize(("security", "key", "words"), [
    ('policy = "None"\ninsecure = true\npassword = "hunter2"', "controller.security",
     "password_file"),
    ('policy = "None"\ninsecure = true\nusername = "u"\npassword_env = "PW"',
     "controller.security", "readable"),
    ('policy = "None"', "controller.security", "insecure = true"),
    ('policy = "Basic256Sha256"\ncertificate = "c.der"\nprivate_key = "k.pem"',
     "controller.security", "pin"),
])
def test_opcua_security_refusals(tmp_path: Path, security: str, key: str, words: str) -> None:
    err = _error(tmp_path, OPCUA.format(security=security))
    assert err.key == key, str(err)
    assert words in err.reason, str(err)
    assert "hunter2" not in str(err)


def test_opcua_insecure_explicit_is_accepted(tmp_path: Path) -> None:
    cfg = load_config(write_config(tmp_path, base=OPCUA.format(security='policy = "None"\n'
                                                            'insecure = true')))
    assert cfg.raw.controller.security is not None


def test_protocol_section_for_another_protocol_is_refused(tmp_path: Path) -> None:
    # a dotted table header belongs to [controller] wherever it stands
    err = _error(tmp_path, MINIMAL + "\n[controller.s7]\nrack = 0\n")
    assert err.key == "controller.s7"


def test_focas_library_path_must_be_absolute(tmp_path: Path) -> None:
    text = MINIMAL.replace('protocol = "modbus"', 'protocol = "focas"').replace(
        "modbus://", "focas://").replace(
        "[channels.bearing]", '[controller.focas]\nlibrary_path = "lib/libfwlib32.so"\n\n'
                              "[channels.bearing]")
    err = _error(tmp_path, text)
    assert err.key == "controller.focas.library_path"
    assert "absolute" in err.reason


def test_unreadable_and_bad_toml(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="cannot read"):
        load_config(tmp_path / "missing.toml")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(write_config(tmp_path, base="[machine\nname="))


def test_check_exits_78_naming_the_key(tmp_path: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    p = write_config(tmp_path, base=MINIMAL.replace("limit_um = 100.0", "limit_um = 0.0"))
    assert main(["check", str(p)]) == EX_CONFIG
    err = capsys.readouterr().err
    assert "output.limit_um" in err


def test_run_exits_78_before_connecting(tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    p = write_config(tmp_path, base=MINIMAL.replace('range = [-20.0, 150.0]',
                                                    'range = [150.0, -20.0]'))
    assert main(["run", str(p)]) == EX_CONFIG
    err = capsys.readouterr().err
    assert "channels.bearing.range: lower bound must be below upper bound" in err


@pytest.mark.parametrize("name", ["modbus", "opcua", "s7", "focas"])
def test_examples_check(name: str, capsys: pytest.CaptureFixture[str]) -> None:
    path = EXAMPLES / f"{name}.toml"
    if not path.exists():
        pytest.skip(f"no example for {name}")
    if name == "focas":  # the vendor library's path: refused by check as by run
        assert main(["check", str(path)]) == EX_CONFIG
        assert "library_path" in capsys.readouterr().err
        return
    assert main(["check", str(path)]) == 0, capsys.readouterr().err
    assert "OK" in capsys.readouterr().out


def test_check_json_reports_model_and_addresses(capsys: pytest.CaptureFixture[str]) -> None:
    import json

    assert main(["check", str(EXAMPLES / "modbus.toml"), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["protocol"] == "modbus"
    assert report["outputs"]["offset"] == "unit1/holding/0:float32"
    assert all(t["stable"] for t in report["model"]["terms"])
