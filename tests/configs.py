"""The tests' config factory: a valid compd config with keyword overrides.

`config_text(base, **keys)` starts from a valid config and sets each named key's
line; `write_config(where, endpoint, ...)` writes one into a folder (the file a
daemon, `compd check` or `compd run` is given); `load_config(write_config(...))`
is its `LoadedConfig`. A base is ``"minimal"`` (`MINIMAL`: the least a config
holds), ``"sim"`` (`SIM`: bearing and ambient in Modbus input registers, offset,
heartbeat and status in holding registers: what
`drivers.sim.modbus_server.ModbusSimController` serves, and the fixture `sim`
publishes), a shipped example's name (``"modbus"``, ``"s7"``, ``"opcua"``,
``"focas"``, ``"linuxcnc"``) or a config's own text.

For a simulated controller of any protocol the config is a document built from
the controller's own addresses (`compd.offline.demo.daemon_config`):
`make_config` (a `LoadedConfig`, recorder off, for the fault tests) and
`lockstep_config` (the document, for `tests.harness.Lockstep`); `merge` lays
the test's overrides over either, `write_doc` writes one.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from models import tomltext
from tests.shipped import EXAMPLES

if TYPE_CHECKING:
    from compd.config.loader import LoadedConfig
    from drivers.sim.base import SimController

__all__ = ["MINIMAL", "SIM", "Toml", "config_text", "lockstep_config", "make_config", "merge",
           "write_config", "write_doc"]

#: the config of the fixture `sim` (any endpoint); 50 machine seconds a real second
SIM = """
[machine]
name = "test"
period_s = 1.0
time_scale = 50.0

[controller]
protocol = "modbus"
endpoint = "modbus://127.0.0.1:5020"
timeout_s = 0.008
connect_timeout_s = 2.0
backoff = { initial_s = 0.02, cap_s = 0.2 }

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
status = { kind = "holding", address = 3, type = "uint16" }
limit_um = 100.0
slew_um_s = 1.0

[faults]
hold_s = 30.0
shutdown = "hold"

[state]
dir = "state"
checkpoint_every = 20

[recorder]
commit_every = 10

[telemetry]
log_format = "json"
"""

#: the least a config holds: bearing and ambient, the offset alone, no [faults],
#: [state] or [recorder] (their defaults)
MINIMAL = """
[machine]
name = "m"
period_s = 1.0

[controller]
protocol = "modbus"
endpoint = "modbus://127.0.0.1:5020"
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
limit_um = 100.0
slew_um_s = 1.0
"""

#: real seconds of the sim config's read timeout per machine second of time_scale
_SIM_TIMEOUT_S = 0.4

#: real seconds the driver may wait for one request and for the connection in a
#: lockstep run: a loaded test machine answers late, never "not at all" (a lockstep
#: run does not depend on them unless the server is really gone)
REQUEST_TIMEOUT_S = 10.0
CONNECT_TIMEOUT_S = 30.0


class Toml(str):
    """A value given as TOML text, put in as written (an inline table, a bare word)."""


def _toml(value: object) -> str:
    return str(value) if isinstance(value, Toml) else tomltext.value(value)


def config_text(base: str = "sim", *, swap: Iterable[tuple[str, str]] = (), extra: str = "",
                **keys: object) -> str:
    """The config `base` (see the module) with each of `keys` set on the first line
    that starts ``key = `` (a str is a TOML string, a `Toml` is put in as written, a
    number, bool, list or dict as TOML writes it; None leaves the line), each (old,
    new) of `swap` replaced where `old` occurs once, and `extra` appended."""
    if base == "sim":
        text = SIM
    elif base == "minimal":
        text = MINIMAL
    elif re.fullmatch(r"[a-z0-9]+", base):
        text = (EXAMPLES / f"{base}.toml").read_text(encoding="utf-8")
    else:
        text = base
    for key, value in keys.items():
        if value is None:
            continue
        line = f"{key} = {_toml(value)}".replace("\\", "\\\\")  # a re template
        text, n = re.subn(rf"(?m)^{re.escape(key)} = .*$", line, text, count=1)
        if n != 1:
            raise KeyError(f"the base config has no line {key!r} = ...")
    for old, new in swap:
        if text.count(old) != 1:
            raise KeyError(f"{old!r} occurs {text.count(old)} times in the base config")
        text = text.replace(old, new)
    return text + extra


def write_config(where: Path, endpoint: str | None = None, *, base: str = "sim",
                 filename: str = "compd.toml", swap: Iterable[tuple[str, str]] = (),
                 extra: str = "", **keys: object) -> Path:
    """`config_text(base, ...)` with `endpoint` written to `where/filename`. On the sim
    base a `time_scale` without a `timeout_s` gets a read timeout of 0.4 machine
    seconds (a fifth of a real second at time_scale 2)."""
    if base == "sim" and keys.get("time_scale") is not None and keys.get("timeout_s") is None:
        keys["timeout_s"] = _SIM_TIMEOUT_S / float(keys["time_scale"])  # type: ignore[arg-type]
    path = where / filename
    path.write_text(config_text(base, swap=swap, extra=extra, endpoint=endpoint, **keys),
                    encoding="utf-8")
    return path


def write_doc(doc: Mapping[str, Any], path: Path) -> Path:
    """A config document written as TOML to `path`."""
    path.write_text(tomltext.dumps(doc), encoding="utf-8")
    return path


def merge(doc: dict[str, Any], overrides: Mapping[str, Any]) -> dict[str, Any]:
    """`overrides` laid over `doc` table by table (a table merges, a value replaces)."""
    for key, value in overrides.items():
        if isinstance(value, Mapping) and isinstance(doc.get(key), dict):
            merge(doc[key], value)
        else:
            doc[key] = value
    return doc


def make_config(sim: SimController, tmp_path: Path, *, time_scale: float,
                overrides: dict[str, Any] | None = None, model: str = "sp2",
                slew_um_s: float = 1.0, limit_um: float = 100.0) -> LoadedConfig:
    """The config for `sim` with the model's channels only and no recorder."""
    from compd.config.loader import parse_config
    from compd.offline.demo import daemon_config

    doc = daemon_config(sim, model=model, period_s=1.0, time_scale=time_scale,
                        state_dir=tmp_path / "state", limit_um=limit_um,
                        slew_um_s=slew_um_s, extra_channels=())
    doc["recorder"] = {"enabled": False}
    merge(doc, overrides or {})
    return parse_config(doc, tmp_path / "compd.toml")


def lockstep_config(sim: SimController, work: Path, *, model: str, period_s: float,
                    **kwargs: Any) -> dict[str, Any]:
    """`compd.offline.demo.daemon_config` for a lockstep run: time_scale 1 (the
    stepped clock counts machine seconds) and generous real-time I/O limits."""
    from compd.offline.demo import daemon_config

    doc = daemon_config(sim, model=model, period_s=period_s, time_scale=1.0,
                        state_dir=work / "state", **kwargs)
    doc["controller"]["timeout_s"] = min(REQUEST_TIMEOUT_S, 0.5 * period_s)
    doc["controller"]["connect_timeout_s"] = CONNECT_TIMEOUT_S
    return doc
