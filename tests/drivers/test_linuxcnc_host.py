"""The machine's one LinuxCNC (`drivers.sim.linuxcnc_host`) and a test controller's
names (no LinuxCNC needed: the lock file and LinuxCNC's own lock are stood in for
by files of the test's)."""

from __future__ import annotations

import fcntl
import os
import subprocess
import sys
import threading
import tomllib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from drivers.sim import linuxcnc_host, linuxcnc_machine
from drivers.sim.linuxcnc_host import ForeignLinuxCnc
from drivers.sim.linuxcnc_machine import LinuxCncSimController

ROOT = Path(__file__).resolve().parents[2]

HOLDER = """
import fcntl, os, sys, time
fd = os.open(sys.argv[1], os.O_RDONLY | os.O_CREAT, 0o666)
fcntl.flock(fd, fcntl.LOCK_EX)
print("held", flush=True)
sys.stdin.readline()
"""


def _stop(proc: subprocess.Popen[str]) -> None:
    proc.kill()
    proc.wait()
    for stream in (proc.stdin, proc.stdout):
        if stream is not None:
            stream.close()


@pytest.fixture
def lock_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """The machine lock and LinuxCNC's own lock file, the test's; nothing running."""
    path = tmp_path / "compd-linuxcnc.lock"
    monkeypatch.setattr(linuxcnc_host, "LOCK_PATH", path)
    monkeypatch.setattr(linuxcnc_host, "LINUXCNC_LOCK", tmp_path / "linuxcnc.lock")
    monkeypatch.setattr(linuxcnc_host, "foreign", lambda: None)
    monkeypatch.setattr(linuxcnc_host, "POLL_S", 0.01)
    yield path
    assert linuxcnc_host._HELD.fd is None  # every test gives it back


def test_a_lock_another_run_holds_is_waited_for(lock_file: Path) -> None:
    """Two runs at once: the second waits for the first, however long it holds the
    machine's LinuxCNC (within hours), and then gets it: slower, never failed."""
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(lock_file)],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    waiter = threading.Thread(target=linuxcnc_host.acquire)
    try:
        assert holder.stdout is not None and holder.stdout.readline() == "held\n"
        waiter.start()
        waiter.join(0.5)
        assert waiter.is_alive()  # waiting: no error however long (a busy machine)
        assert holder.stdin is not None
        holder.stdin.close()  # the other run ends
        waiter.join(60.0)
        assert not waiter.is_alive() and linuxcnc_host._HELD.fd is not None
    finally:
        _stop(holder)
        waiter.join(60.0)
        linuxcnc_host.release()


def test_a_long_wait_is_no_error_before_hours(lock_file: Path) -> None:
    """The wait's bound is hours (not a test's minutes); past it the run is told the
    machine is busy (a skip), never an error of the test."""
    assert linuxcnc_host.LOCK_WAIT_S >= 3600.0
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(lock_file)],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline() == "held\n"
        with pytest.raises(linuxcnc_host.LinuxCncBusy, match="one LinuxCNC per machine"):
            linuxcnc_host.acquire(wait_s=0.05)
    finally:
        _stop(holder)


def test_the_lock_is_one_for_the_machine() -> None:
    """HAL is one per machine: the lock is too, whatever TMPDIR a user or CI job has."""
    assert Path("/tmp/compd-linuxcnc.lock") == linuxcnc_host.LOCK_PATH


def test_a_linuxcnc_nobody_here_started_is_left_alone(lock_file: Path, tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """Holding the lock, a LinuxCNC that runs (here: its lock file) is somebody
    else's: refused with the reason, and the machine's lock given back at once."""
    monkeypatch.undo()
    monkeypatch.setattr(linuxcnc_host, "LOCK_PATH", lock_file)
    monkeypatch.setattr(linuxcnc_host, "LINUXCNC_LOCK", tmp_path / "linuxcnc.lock")
    (tmp_path / "linuxcnc.lock").touch()
    with pytest.raises(ForeignLinuxCnc, match=r"linuxcnc\.lock exists"):
        linuxcnc_host.acquire()
    assert linuxcnc_host._HELD.fd is None
    with _Free(lock_file):  # given back: another run takes it at once
        pass


class _Free:
    """The lock taken (not waited for) by a fresh descriptor: nobody holds it."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def __enter__(self) -> None:
        self.fd = os.open(self.path, os.O_RDONLY)
        fcntl.flock(self.fd, fcntl.LOCK_EX | fcntl.LOCK_NB)

    def __exit__(self, *exc: object) -> None:
        os.close(self.fd)


async def test_the_controller_never_cleans_up_a_linuxcnc_it_did_not_start(
        lock_file: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A shop's LinuxCNC on the test machine: the test controller refuses to start
    (the tests skip with the reason) and runs neither ``halrun -U`` nor ``linuxcnc``
    (whose start script would clean the other instance up by itself)."""
    calls: list[list[str]] = []

    def spy(args: list[str], *a: Any, **k: Any) -> Any:
        calls.append(list(args))
        raise AssertionError(f"ran {args}")

    monkeypatch.setattr(linuxcnc_host, "foreign", lambda: "the LinuxCNC process rtapi_app")
    monkeypatch.setattr(linuxcnc_machine, "unavailable", lambda: None)
    monkeypatch.setattr(subprocess, "run", spy)
    monkeypatch.setattr(subprocess, "Popen", spy)
    sim = LinuxCncSimController()
    with pytest.raises(ForeignLinuxCnc, match="did not start"):
        await sim.start()
    assert calls == []


def test_a_test_machines_names_are_the_runs_own() -> None:
    """Signals and components carry the run's prefix: a compd a test leaves running
    finds none of them in another LinuxCNC (refused by name, never writing)."""
    sim = LinuxCncSimController()
    assert sim.prefix != "compd" and sim.component == sim.prefix
    nets = [a.net for a in sim.channels.values() if a.net != "spindle-speed-cmd"]
    nets += [sim.outputs_map["offset"].counts_net, sim.outputs_map["offset"].enable_net]
    nets += [sim.outputs_map[n].net for n in ("heartbeat", "status")]
    nets += [a.net for a in sim.mcode_inputs.values()]
    assert all(n.startswith(sim.prefix + "-") for n in nets)
    assert "compd-" not in linuxcnc_machine.hal_lines(sim.prefix).replace(sim.prefix, "")
    assert "compd-" not in linuxcnc_machine.mcode_hal_lines(sim.prefix).replace(
        sim.prefix, "")
    doc = sim.own_config(tomllib.loads(
        (ROOT / "compd" / "examples" / "linuxcnc.toml").read_text("utf-8")))
    assert doc["controller"]["linuxcnc"]["component"] == sim.prefix
    assert doc["channels"]["bearing"]["address"]["net"] == f"{sim.prefix}-bearing"
    assert doc["output"]["offset"]["counts_net"] == f"{sim.prefix}-eoffset-counts"
    assert doc["channels"]["spindle_rpm"]["address"]["net"] == "spindle-speed-cmd"
