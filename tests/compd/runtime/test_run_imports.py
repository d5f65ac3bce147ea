"""`compd run` for a Modbus controller does not import what it does not use.

A fresh interpreter does what `compd run` does before its loop (load the
config, configure logging, build the driver, construct the daemon) and prints
sorted(sys.modules): scipy and matplotlib (about 66 MB of resident memory),
and the other protocols' libraries (asyncua, snap7), must not be there.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

_PROBE = """
import json, sys
from compd.commands import run  # noqa: F401  (the command module, as the CLI loads it)
from compd.config.loader import load_config
from compd.runtime.daemon import Daemon
from compd.runtime.driver_setup import build_driver
from compd.faces.telemetry import configure_logging

cfg = load_config(sys.argv[1])
configure_logging(json=True, level="info")
Daemon(cfg, driver=build_driver(cfg))
print(json.dumps(sorted(sys.modules)))
"""

_CONFIG = """
[machine]
name = "imports"

[controller]
protocol = "modbus"
endpoint = "modbus://127.0.0.1:1"

[channels.bearing]
address = {{ unit = 1, kind = "input", address = 0, type = "int16", scale = 0.1 }}
unit = "degC"
range = [-20.0, 150.0]

[channels.ambient]
address = {{ unit = 1, kind = "input", address = 4, type = "int16", scale = 0.1 }}
unit = "degC"
range = [-10.0, 60.0]

[model]
file = "sp2"

[output]
offset = {{ unit = 1, kind = "holding", address = 0, type = "float32" }}
limit_um = 200.0
slew_um_s = 1.0

[state]
dir = "{state}"
"""


def test_modbus_run_imports_no_scipy_matplotlib_or_other_drivers(tmp_path: Path) -> None:
    config = tmp_path / "compd.toml"
    config.write_text(_CONFIG.format(state=tmp_path / "state"), encoding="utf-8")
    proc = subprocess.run([sys.executable, "-c", _PROBE, str(config)], capture_output=True,
                          text=True, timeout=60, check=False)
    assert proc.returncode == 0, proc.stderr
    modules = set(json.loads(proc.stdout.strip().splitlines()[-1]))
    tops = {name.split(".")[0] for name in modules}
    assert "compd.runtime.daemon" in modules and "drivers.modbus" in modules
    assert "pymodbus" in tops
    loaded = {"scipy", "matplotlib", "asyncua", "snap7"} & tops
    assert not loaded, f"compd run for Modbus imported {sorted(loaded)}"
