"""The README's "Against a simulated machine" sequence works as written.

The two commands are taken from the README itself, the protocol swapped in
as the README says, and run as a user runs them: `compd sim` as a process in
an empty folder, and once it has printed that it serves, `compd run` on the
config it wrote, with ``--once`` (one cycle, its result as JSON) so that the
test ends. No fixed port: the sim takes a free one and writes it.
"""

from __future__ import annotations

import json
import re
import shlex
import signal
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PROTOCOLS = ["opcua", "s7", "modbus", "focas"]


def _readme_commands() -> list[list[str]]:
    """The commands of the first sh block under "## Against a simulated machine"."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text.split("## Against a simulated machine", 1)[1]
    block = re.search(r"```sh\n(.*?)```", section, re.S)
    assert block is not None
    return [shlex.split(line, comments=True) for line in block.group(1).splitlines()
            if line.strip()]


def test_the_readme_names_the_sequence() -> None:
    sim, run = _readme_commands()
    assert sim[:2] == ["compd", "sim"] and "--write-config" in sim
    assert run[:2] == ["compd", "run"]
    assert run[2] == sim[sim.index("--write-config") + 1]  # runs the config the sim wrote


def _as_written(argv: list[str], protocol: str) -> list[str]:
    """A README line for `protocol` (its words "opcua" swapped, as the README
    says), run by this interpreter's compd."""
    words = [w.replace("opcua", protocol) for w in argv[1:]]
    return [sys.executable, "-m", "compd", *words]


@pytest.mark.parametrize("protocol", PROTOCOLS)
def test_the_readme_sequence_compensates_each_protocol(protocol: str, tmp_path: Path) -> None:
    sim_argv, run_argv = (_as_written(c, protocol) for c in _readme_commands())
    sim = subprocess.Popen(sim_argv, cwd=tmp_path, stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True)
    try:
        assert sim.stdout is not None
        first = sim.stdout.readline()  # printed once it serves and the config is written
        assert first.startswith(f"compd sim: {protocol} controller at "), (
            first, sim.stderr.read() if sim.poll() is not None and sim.stderr else "")
        run = subprocess.run([*run_argv, "--once"], check=False, cwd=tmp_path,
                             capture_output=True, text=True, timeout=240)
    finally:
        sim.send_signal(signal.SIGINT)
        sim.communicate(timeout=60)
    assert run.returncode == 0, run.stderr[-2000:]
    result = json.loads(run.stdout.splitlines()[-1])
    assert result["complete"] is True and result["state"] == "ok"
    assert set(result["writes"]) >= {"offset", "heartbeat", "status"}
    assert 15.0 < result["channels"]["bearing"] < 40.0  # the sim's sensor, read over the wire
    assert sim.returncode == 0
    config = (tmp_path / f"{protocol}.toml").read_text(encoding="utf-8")
    assert "time_scale = 60.0" in config
    assert (tmp_path / f"state-{protocol}").is_dir()  # beside the config, not a shared /tmp
