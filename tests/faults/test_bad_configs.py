"""Bad configurations: each is refused by `compd check` and by `compd run`
with exit code 78 and a message naming the key, and the controller endpoint
(a listening socket on 127.0.0.1) is never connected to.

The cases are edits of a valid config per protocol: wrong types, missing
addresses, unknown units, unstable models, security policy None with a
password, a limit of 0, addresses of another protocol, negative periods,
timeouts above half the period, unknown sections, bad model files, a
relative FOCAS library path, ... Most run in-process through
`compd.cli.main`; a handful go through a `compd run` subprocess.
"""

from __future__ import annotations

import socket
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from compd.cli import main
from compd.config.loader import load_config
from compd.errors import EX_CONFIG, ConfigError
from tests.faults.daemon_run import ROOT, daemon_env, forget_daemon_logging

MODBUS = """
[machine]
name = "m"
period_s = 1.0

[controller]
protocol = "modbus"
endpoint = "modbus://127.0.0.1:{port}"
timeout_s = 0.2

[channels.bearing]
address = { kind = "input", address = 0, type = "int16", scale = 0.1 }
unit = "degC"
range = [-20.0, 150.0]

[channels.ambient]
address = { kind = "input", address = 4, type = "int16", scale = 0.1 }
unit = "degC"
range = [-10.0, 60.0]

[model]
file = "sp2"

[output]
offset = { kind = "holding", address = 0, type = "float32" }
heartbeat = { kind = "holding", address = 2, type = "uint16" }
limit_um = 100.0
slew_um_s = 1.0

[state]
dir = "state"
"""

OPCUA = """
[machine]
period_s = 1.0

[controller]
protocol = "opcua"
endpoint = "opc.tcp://127.0.0.1:{port}"
timeout_s = 0.2

[controller.security]
policy = "None"
insecure = true

[channels.bearing]
address = { node = "ns=2;s=Machine.bearing" }
unit = "degC"
range = [-20.0, 150.0]

[channels.ambient]
address = { node = "ns=2;s=Machine.ambient" }
unit = "degC"
range = [-10.0, 60.0]

[model]
file = "sp2"

[output]
offset = { node = "ns=2;s=Machine.offset" }
limit_um = 100.0
slew_um_s = 1.0

[state]
dir = "state"
"""

S7 = """
[controller]
protocol = "s7"
endpoint = "s7://127.0.0.1:{port}"
timeout_s = 0.2

[controller.s7]
rack = 0
slot = 1

[channels.bearing]
address = { db = 1, offset = 0, type = "INT", scale = 0.1 }
unit = "degC"
range = [-20.0, 150.0]

[channels.ambient]
address = { db = 1, offset = 8, type = "INT", scale = 0.1 }
unit = "degC"
range = [-10.0, 60.0]

[model]
file = "sp2"

[output]
offset = { db = 2, offset = 0, type = "REAL" }
limit_um = 100.0
slew_um_s = 1.0

[state]
dir = "state"
"""

FOCAS = """
[controller]
protocol = "focas"
endpoint = "focas://127.0.0.1:{port}"
timeout_s = 0.2

[controller.focas]
library_path = "/usr/local/lib/libfwlib32.so"

[channels.bearing]
address = { kind = "pmc", area = "D", address = 0, type = "word", scale = 0.1 }
unit = "degC"
range = [-20.0, 150.0]

[channels.ambient]
address = { kind = "pmc", area = "D", address = 6, type = "word", scale = 0.1 }
unit = "degC"
range = [-10.0, 60.0]

[model]
file = "sp2"

[output]
offset = { kind = "pmc", area = "D", address = 100, type = "long", scale = 0.1 }
limit_um = 100.0
slew_um_s = 1.0

[state]
dir = "state"
"""

LINUXCNC = """
[controller]
protocol = "linuxcnc"
endpoint = "linuxcnc://localhost"
timeout_s = 0.2

[controller.linuxcnc]
component = "compd"

[channels.bearing]
address = { pin = "bearing", net = "compd-bearing" }
unit = "degC"
range = [-20.0, 150.0]

[channels.ambient]
address = { pin = "ambient", net = "compd-ambient" }
unit = "degC"
range = [-10.0, 60.0]

[model]
file = "sp2"

[output]
offset = { kind = "eoffset", axis = "z" }
heartbeat = { pin = "heartbeat", net = "compd-heartbeat", type = "s32" }
machine_on = { pin = "machine-on", net = "compd-machine-on", type = "bit" }
limit_um = 100.0
slew_um_s = 1.0

[state]
dir = "state"
"""

BASES = {"modbus": MODBUS, "opcua": OPCUA, "s7": S7, "focas": FOCAS, "linuxcnc": LINUXCNC}

UNSTABLE_MODEL = """
[model]
name = "runaway"
period_s = 1.0
channels = ["bearing"]

[[terms]]
name = "spindle"
inputs = { bearing = 1.0 }
a = ["1.0"]
b = ["1", "-1.2"]
"""

SPINDLE_ADDR = 'address = { kind = "input", address = 0, type = "int16", scale = 0.1 }'
OFFSET_ADDR = 'offset = { kind = "holding", address = 0, type = "float32" }'
BEARING_BLOCK = f'[channels.bearing]\n{SPINDLE_ADDR}\nunit = "degC"\nrange = [-20.0, 150.0]\n'
AMBIENT_BLOCK = ('[channels.ambient]\naddress = { kind = "input", address = 4, type = "int16", '
                 'scale = 0.1 }\nunit = "degC"\nrange = [-10.0, 60.0]\n')
SEC_NONE = 'policy = "None"\ninsecure = true'
SEC_B256 = ('policy = "Basic256Sha256"\ncertificate = "c.der"\nprivate_key = "k.pem"\n'
            'server_certificate = "s.der"')


@dataclass(frozen=True)
class Case:
    id: str
    base: str
    edits: tuple[tuple[str, str], ...]
    key: str
    words: str
    files: dict[str, str] = field(default_factory=dict)


def _c(id_: str, base: str, old: str, new: str, key: str, words: str,
       files: dict[str, str] | None = None) -> Case:
    return Case(id_, base, ((old, new),), key, words, files or {})


CASES: list[Case] = [
    # --- wrong types ---
    _c("period-string", "modbus", "period_s = 1.0", 'period_s = "fast"', "machine.period_s",
       "number"),
    _c("limit-string", "modbus", "limit_um = 100.0", 'limit_um = "100"', "output.limit_um",
       "number"),
    _c("slew-bool", "modbus", "slew_um_s = 1.0", "slew_um_s = [1.0]", "output.slew_um_s",
       "number"),
    _c("range-scalar", "modbus", "range = [-20.0, 150.0]", "range = 150.0",
       "channels.bearing.range", "tuple"),
    _c("range-three", "modbus", "range = [-20.0, 150.0]", "range = [-20.0, 0.0, 150.0]",
       "channels.bearing.range", "2"),
    _c("unit-number", "modbus", 'unit = "degC"\nrange = [-20.0', "unit = 5\nrange = [-20.0",
       "channels.bearing.unit", "string"),
    _c("timeout-string", "modbus", "timeout_s = 0.2", 'timeout_s = "0.2s"',
       "controller.timeout_s", "number"),
    _c("address-string", "modbus", SPINDLE_ADDR, 'address = "40001"',
       "channels.bearing.address", "dict"),
    _c("register-float", "modbus", SPINDLE_ADDR,
       'address = { kind = "input", address = 1.5, type = "int16" }',
       "channels.bearing.address.address", "integer"),
    _c("sign-two", "modbus", "slew_um_s = 1.0", "slew_um_s = 1.0\nsign = 2", "output.sign",
       "1"),
    _c("readback-string", "modbus", "slew_um_s = 1.0", 'slew_um_s = 1.0\nreadback = "yes"',
       "output.readback", "boolean"),
    _c("channels-not-table", "modbus", "[channels.ambient]", "[channels_x.ambient]",
       "channels_x", "unknown key"),
    _c("checkpoint-every-zero", "modbus", 'dir = "state"', 'dir = "state"\ncheckpoint_every = 0',
       "state.checkpoint_every", "greater than or equal"),
    _c("metrics-port-big", "modbus", "[state]", "[telemetry]\nmetrics_port = 70000\n\n[state]",
       "telemetry.metrics_port", "less than or equal"),
    _c("log-level-bad", "modbus", "[state]", '[telemetry]\nlog_level = "loud"\n\n[state]',
       "telemetry.log_level", "debug"),
    # --- missing keys / addresses ---
    _c("no-offset", "modbus", OFFSET_ADDR, "", "output.offset", "missing"),
    _c("no-channel-address", "modbus", SPINDLE_ADDR, "", "channels.bearing.address",
       "missing"),
    _c("no-register", "modbus", SPINDLE_ADDR, 'address = { kind = "input", type = "int16" }',
       "channels.bearing.address.address", "missing"),
    _c("no-endpoint", "modbus", 'endpoint = "modbus://127.0.0.1:{port}"', "",
       "controller.endpoint", "missing"),
    _c("empty-endpoint", "modbus", 'endpoint = "modbus://127.0.0.1:{port}"', 'endpoint = ""',
       "controller.endpoint", "at least 1"),
    _c("no-protocol", "modbus", 'protocol = "modbus"', "", "controller.protocol", "missing"),
    _c("no-limit", "modbus", "limit_um = 100.0", "", "output.limit_um", "missing"),
    _c("no-model", "modbus", '[model]\nfile = "sp2"', "", "model", "missing"),
    Case("no-channels", "modbus", ((BEARING_BLOCK, ""), (AMBIENT_BLOCK, ""),
                                   ("[machine]", "channels = {}\n[machine]")),
         "channels", "at least one"),
    _c("model-needs-ambient", "modbus", "[channels.ambient]", "[channels.ambient2]",
       "model.file", "unknown channel"),
    _c("s7-no-db", "s7", 'address = { db = 1, offset = 0, type = "INT", scale = 0.1 }',
       'address = { offset = 0, type = "INT" }', "channels.bearing.address.db", "missing"),
    _c("opcua-no-node", "opcua", 'address = { node = "ns=2;s=Machine.bearing" }',
       "address = { scale = 1.0 }", "channels.bearing.address.node", "missing"),
    _c("opcua-no-security", "opcua", "[controller.security]\n" + SEC_NONE, "",
       "controller.security", "needs"),
    _c("opcua-empty-security", "opcua", SEC_NONE, "", "controller.security",
       "insecure = true"),
    _c("focas-no-section", "focas", '[controller.focas]\nlibrary_path = '
       '"/usr/local/lib/libfwlib32.so"', "", "controller.focas", "library_path"),
    # --- unknown units, unknown keys, unknown sections ---
    _c("unit-furlong", "modbus", 'unit = "degC"\nrange = [-20.0', 'unit = "furlong"\nrange = '
       "[-20.0", "channels.bearing.unit", "unknown unit"),
    _c("unit-fahrenheit", "s7", 'unit = "degC"\nrange = [-20.0', 'unit = "degF"\nrange = '
       "[-20.0", "channels.bearing.unit", "unknown unit"),
    _c("output-unit-yard", "modbus", "slew_um_s = 1.0", 'slew_um_s = 1.0\nunit = "yard"',
       "output.unit", "um"),
    _c("count-without-scale", "modbus", "slew_um_s = 1.0", 'slew_um_s = 1.0\nunit = "count"',
       "output", "scale"),
    _c("unknown-section", "modbus", "[state]", "[plc]\nenabled = true\n\n[state]", "plc",
       "unknown key"),
    _c("unknown-key-output", "modbus", "slew_um_s = 1.0", "slew_um_s = 1.0\nbogus = 3",
       "output.bogus", "unknown key"),
    _c("unknown-key-machine", "modbus", 'name = "m"', 'name = "m"\nspeed = 3',
       "machine.speed", "unknown key"),
    _c("unknown-protocol", "modbus", 'protocol = "modbus"', 'protocol = "profibus"',
       "controller.protocol", "opcua"),
    _c("inline-password", "opcua", SEC_NONE, SEC_NONE + '\npassword = "hunter2"',
       "controller.security", "password_file"),
    # --- numbers out of range ---
    _c("limit-zero", "modbus", "limit_um = 100.0", "limit_um = 0", "output.limit_um",
       "greater than 0"),
    _c("limit-negative", "s7", "limit_um = 100.0", "limit_um = -5.0", "output.limit_um",
       "greater than 0"),
    _c("limit-inf", "modbus", "limit_um = 100.0", "limit_um = inf", "output.limit_um",
       "finite"),
    _c("slew-zero", "modbus", "slew_um_s = 1.0", "slew_um_s = 0.0", "output.slew_um_s",
       "greater than or equal to 0.001"),
    _c("slew-nan", "opcua", "slew_um_s = 1.0", "slew_um_s = nan", "output.slew_um_s",
       "finite"),
    _c("period-negative", "modbus", "period_s = 1.0", "period_s = -1.0", "machine.period_s",
       "greater than or equal to 0.01"),
    _c("period-zero", "opcua", "period_s = 1.0", "period_s = 0", "machine.period_s",
       "greater than or equal to 0.01"),
    _c("time-scale-negative", "modbus", "period_s = 1.0", "period_s = 1.0\ntime_scale = -10",
       "machine.time_scale", "greater than 0"),
    _c("timeout-above-half-period", "modbus", "timeout_s = 0.2", "timeout_s = 0.7",
       "controller.timeout_s", "half"),
    _c("timeout-above-half-real-period", "opcua", "period_s = 1.0",
       "period_s = 1.0\ntime_scale = 10.0", "controller.timeout_s", "half"),
    _c("timeout-negative", "s7", "timeout_s = 0.2", "timeout_s = -0.1",
       "controller.timeout_s", "greater than 0"),
    _c("deadband-above-limit", "modbus", "slew_um_s = 1.0", "slew_um_s = 1.0\n"
       "deadband_um = 150.0", "output", "deadband"),
    _c("range-reversed", "modbus", "range = [-20.0, 150.0]", "range = [150.0, -20.0]",
       "channels.bearing.range", "lower bound"),
    _c("range-infinite", "modbus", "range = [-20.0, 150.0]", "range = [-inf, 150.0]",
       "channels.bearing.range", "finite"),
    _c("backoff-inverted", "modbus", "timeout_s = 0.2",
       "timeout_s = 0.2\nbackoff = { initial_s = 5.0, cap_s = 1.0 }",
       "controller.backoff", "cap_s"),
    _c("scale-zero", "modbus", SPINDLE_ADDR,
       'address = { kind = "input", address = 0, type = "int16", scale = 0.0 }',
       "channels.bearing.address.scale", "non-zero"),
    _c("register-too-big", "modbus", SPINDLE_ADDR,
       'address = { kind = "input", address = 70000, type = "int16" }',
       "channels.bearing.address.address", "less than or equal"),
    _c("modbus-unit-too-big", "modbus", OFFSET_ADDR,
       'offset = { unit = 300, kind = "holding", address = 0, type = "float32" }',
       "output.offset.unit", "less than or equal"),
    _c("s7-rack-too-big", "s7", "rack = 0", "rack = 9", "controller.s7.rack",
       "less than or equal"),
    _c("hold-negative", "modbus", "[state]", "[faults]\nhold_s = -1.0\n\n[state]",
       "faults.hold_s", "greater than or equal"),
    # --- wrong-protocol addresses ---
    _c("opcua-address-on-modbus", "modbus", SPINDLE_ADDR,
       'address = { node = "ns=2;s=Machine.bearing" }', "channels.bearing.address",
       "opcua address"),
    _c("s7-address-on-modbus", "modbus", OFFSET_ADDR,
       'offset = { db = 2, offset = 0, type = "REAL" }', "output.offset", "s7 address"),
    _c("modbus-address-on-s7", "s7", 'address = { db = 1, offset = 0, type = "INT", '
       'scale = 0.1 }', SPINDLE_ADDR, "channels.bearing.address", "modbus address"),
    _c("focas-address-on-opcua", "opcua", 'offset = { node = "ns=2;s=Machine.offset" }',
       'offset = { kind = "pmc", area = "D", address = 100, type = "long" }', "output.offset",
       "focas address"),
    _c("bad-nodeid", "opcua", 'address = { node = "ns=2;s=Machine.bearing" }',
       'address = { node = "Machine.bearing" }', "channels.bearing.address.node",
       "nodeid"),
    _c("s7-section-on-modbus", "modbus", "[channels.bearing]",
       "[controller.s7]\nrack = 0\n\n[channels.bearing]", "controller.s7", "s7"),
    _c("focas-section-on-opcua", "opcua", "[channels.bearing]",
       '[controller.focas]\nlibrary_path = "/x.so"\n\n[channels.bearing]',
       "controller.focas", "focas"),
    _c("output-name-as-channel", "modbus", "[channels.ambient]",
       '[channels.offset]\naddress = { kind = "input", address = 9, type = "int16" }\n'
       'unit = "um"\nrange = [-1.0, 1.0]\n\n[channels.ambient]', "channels.offset",
       "reserved"),
    # --- security ---
    _c("policy-none-with-password-file", "opcua", SEC_NONE,
       SEC_NONE + '\nusername = "u"\npassword_file = "pw.txt"', "controller.security",
       "readable", {"pw.txt": "s3cret-Pw\n"}),
    _c("policy-none-with-password-env", "opcua", SEC_NONE,
       SEC_NONE + '\nusername = "u"\npassword_env = "COMPD_PW"', "controller.security",
       "readable"),
    _c("policy-none-not-insecure", "opcua", SEC_NONE, 'policy = "None"',
       "controller.security", "insecure = true"),
    _c("policy-deprecated-basic128", "opcua", SEC_NONE, 'policy = "Basic128Rsa15"',
       "controller.security.policy", "basic256sha256"),
    _c("policy-deprecated-basic256", "opcua", SEC_NONE, 'policy = "Basic256"',
       "controller.security.policy", "basic256sha256"),
    _c("policy-unpinned", "opcua", SEC_NONE,
       'policy = "Basic256Sha256"\ncertificate = "c.der"\nprivate_key = "k.pem"',
       "controller.security", "pin"),
    _c("policy-no-cert", "opcua", SEC_NONE, 'policy = "Aes256_Sha256_RsaPss"\n'
       'server_certificate = "s.der"', "controller.security", "certificate"),
    _c("password-no-username", "opcua", SEC_NONE, SEC_B256 + '\npassword_env = "COMPD_PW"',
       "controller.security", "username"),
    _c("password-file-missing", "opcua", SEC_NONE,
       SEC_B256 + '\nusername = "u"\npassword_file = "missing-pw.txt"',
       "controller.security.password_file", "no such file"),
    _c("mode-none", "opcua", SEC_NONE, SEC_B256 + '\nmode = "None"',
       "controller.security.mode", "sign"),
    _c("linuxcnc-bad-net", "linuxcnc", 'net = "compd-bearing"', 'net = "compd bearing"',
       "channels.bearing.address.pin.net", "not a HAL name"),
    _c("linuxcnc-invert-float", "linuxcnc", 'net = "compd-ambient" }',
       'net = "compd-ambient", invert = true }', "channels.ambient.address.pin",
       "invert is for a bit pin only"),
    _c("linuxcnc-relative-python", "linuxcnc", 'component = "compd"',
       'component = "compd"\npython = "python3"', "controller.linuxcnc.python",
       "absolute path"),
    _c("linuxcnc-component-spindle", "linuxcnc", 'component = "compd"',
       'component = "spindle"', "controller.linuxcnc.component", "LinuxCNC uses"),
    _c("linuxcnc-component-motion-dot", "linuxcnc", 'component = "compd"',
       'component = "Motion.compd"', "controller.linuxcnc.component", "LinuxCNC uses"),
    _c("linuxcnc-pin-too-long", "linuxcnc", 'pin = "bearing"', 'pin = "' + "b" * 40 + '"',
       "channels.bearing.address.pin", "too long"),
    _c("linuxcnc-remote-endpoint", "linuxcnc", 'endpoint = "linuxcnc://localhost"',
       'endpoint = "linuxcnc://mill-3.shop"', "controller.endpoint", "local shared memory"),
    _c("focas-relative-library", "focas", 'library_path = "/usr/local/lib/libfwlib32.so"',
       'library_path = "lib/libfwlib32.so"', "controller.focas.library_path", "absolute"),
    _c("focas-bad-sha", "focas", 'library_path = "/usr/local/lib/libfwlib32.so"',
       'library_path = "/usr/local/lib/libfwlib32.so"\nlibrary_sha256 = "abc"',
       "controller.focas.library_sha256", "64 hex"),
    # --- models ---
    _c("unstable-model-file", "modbus", 'file = "sp2"', 'file = "runaway.toml"', "model.file",
       "unstable", {"runaway.toml": UNSTABLE_MODEL}),
    _c("unstable-inline-model", "s7", 'file = "sp2"',
       '[[model.terms]]\nname = "runaway"\ninputs = { bearing = 1.0 }\na = ["1.0"]\n'
       'b = ["1", "-1.5"]', "model.terms", "unstable"),
    _c("model-file-missing", "modbus", 'file = "sp2"', 'file = "nonexistent.toml"',
       "model.file", "no model file"),
    _c("model-file-not-toml", "modbus", 'file = "sp2"', 'file = "junk.toml"', "model.file",
       "", {"junk.toml": "[model\nname = "}),
    _c("model-file-no-terms", "modbus", 'file = "sp2"', 'file = "empty.toml"', "model.file",
       "", {"empty.toml": '[model]\nname = "e"\nperiod_s = 1.0\n'}),
    _c("model-file-bad-coefficient", "modbus", 'file = "sp2"', 'file = "bad.toml"',
       "model.file", "", {"bad.toml": UNSTABLE_MODEL.replace('"-1.2"', '"minus one"')}),
    _c("model-period-mismatch", "modbus", "period_s = 1.0", "period_s = 2.0", "model.file",
       "period_s"),
    _c("model-file-and-terms", "modbus", 'file = "sp2"',
       'file = "sp2"\n[[model.terms]]\nname = "x"\ninputs = { bearing = 1.0 }\na = ["1"]\n'
       'b = ["1", "-0.5"]', "model", "exactly one"),
    _c("shadow-unstable", "modbus", 'file = "sp2"', 'file = "sp2"\nshadow = "runaway.toml"',
       "model.shadow", "unstable", {"runaway.toml": UNSTABLE_MODEL}),
    _c("inline-unknown-channel", "modbus", 'file = "sp2"',
       '[[model.terms]]\nname = "t"\ninputs = { spindle_nose = 1.0 }\na = ["0.5"]\n'
       'b = ["1", "-0.5"]', "model.terms", "spindle_nose"),
]


def _no_connection(sock: socket.socket) -> None:
    with pytest.raises(BlockingIOError):
        conn, _ = sock.accept()
        conn.close()


def _write(case: Case, tmp_path: Path, port: int) -> Path:
    text = BASES[case.base]
    for old, new in case.edits:
        assert old in text, f"{case.id}: {old!r} not in the {case.base} base"
        text = text.replace(old, new, 1)
    for name, content in case.files.items():
        (tmp_path / name).write_text(content, encoding="utf-8")
    path = tmp_path / "compd.toml"
    path.write_text(text.replace("{port}", str(port)), encoding="utf-8")
    return path


def test_at_least_50_cases_with_unique_ids() -> None:
    assert len(CASES) >= 50
    assert len({c.id for c in CASES}) == len(CASES)


@pytest.mark.parametrize("base", sorted(BASES))
def test_the_bases_are_valid(base: str, tmp_path: Path, listener: socket.socket) -> None:
    p = tmp_path / "compd.toml"
    p.write_text(BASES[base].replace("{port}", str(listener.getsockname()[1])))
    load_config(p)


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_refused_by_check_and_run_with_78_naming_the_key(
        case: Case, tmp_path: Path, listener: socket.socket,
        capsys: pytest.CaptureFixture[str]) -> None:
    path = _write(case, tmp_path, listener.getsockname()[1])
    with pytest.raises(ConfigError) as info:
        load_config(path)
    err = info.value
    assert err.key == case.key, str(err)
    assert case.words.lower() in err.reason.lower(), str(err)
    assert "hunter2" not in str(err) and "s3cret" not in str(err)
    capsys.readouterr()
    for command in ("check", "run"):
        try:
            rc = main([command, str(path)])
        finally:
            forget_daemon_logging()
        out = capsys.readouterr()
        assert rc == EX_CONFIG, (command, out.err)
        assert f"compd: configuration error: {case.key}" in out.err, (command, out.err)
    _no_connection(listener)
    assert not (tmp_path / "state").exists()  # nothing started: no lock, no recorder


SUBPROCESS_CASES = ["limit-zero", "unit-furlong", "policy-none-with-password-file",
                    "timeout-above-half-period", "focas-relative-library",
                    "unstable-model-file"]


@pytest.mark.parametrize("case_id", SUBPROCESS_CASES)
def test_refused_by_a_compd_run_process(case_id: str, tmp_path: Path,
                                        listener: socket.socket) -> None:
    case = next(c for c in CASES if c.id == case_id)
    path = _write(case, tmp_path, listener.getsockname()[1])
    for command in ("check", "run"):
        res = subprocess.run([sys.executable, "-m", "compd", command, str(path)],
                             capture_output=True, text=True, env=daemon_env(), cwd=ROOT,
                             timeout=60, check=False)
        assert res.returncode == EX_CONFIG, res
        assert case.key in res.stderr, res.stderr
        assert "Traceback" not in res.stderr
    _no_connection(listener)
