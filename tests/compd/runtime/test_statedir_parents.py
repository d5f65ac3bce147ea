"""The state directory's parents from a local attacker's side.

Parents created 0777 under ``umask 000`` would let another user rename the
state directory away and put a link in its place, and the root daemon would
replace the link target's ``checkpoint.json``; a hard link planted at
``samples.sqlite-shm`` would have its target overwritten by SQLite. So:
parents are created 0755 whatever the umask, a parent another user could
rename entries in is refused (78, naming it), the state directory is opened
once and everything in it is done relative to that descriptor, and every
name compd or SQLite opens is refused when it is a link or a hard link.

One user (the tests') plays both sides: the swap is done between the daemon's
open of the directory and its checkpoint writes."""

from __future__ import annotations

import json
import os
import stat
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from compd.runtime.checkpoint import load_checkpoint, save_checkpoint
from compd.runtime.recorder import Recorder, RecorderError
from compd.runtime.statedir import StateDir, StateDirError, UnsafeParent
from compd.runtime.statelock import LOCK_NAME, StateLock
from compd.sysexits import EX_CONFIG
from tests.configs import write_config

ROOT = Path(__file__).resolve().parents[3]
PRECIOUS = '{"precious": true}\n'


@pytest.fixture
def umask_000() -> Iterator[None]:
    old = os.umask(0)
    try:
        yield
    finally:
        os.umask(old)


def _base(tmp_path: Path) -> Path:
    """A world-writable, sticky place like /tmp."""
    base = tmp_path / "base"
    base.mkdir()
    os.chmod(base, 0o1777)
    return base


def _mode(path: Path) -> int:
    return stat.S_IMODE(os.lstat(path).st_mode)


def _victim_dir(base: Path) -> Path:
    vict = base / "vict"
    vict.mkdir(mode=0o700)
    (vict / "checkpoint.json").write_text(PRECIOUS)
    return vict


# -- creating the way -------------------------------------------------------------------


def test_umask_000_creates_parents_0755_and_the_state_dir_0700(
        tmp_path: Path, umask_000: None) -> None:
    base = _base(tmp_path)
    state = base / "n" / "x" / "y" / "state"
    lock = StateLock(state)
    lock.acquire()
    try:
        modes = {p.name: _mode(p) for p in (base / "n", base / "n" / "x", state.parent, state)}
        assert modes == {"n": 0o755, "x": 0o755, "y": 0o755, "state": 0o700}, modes
        assert _mode(state / LOCK_NAME) == 0o600
    finally:
        lock.release()


def test_umask_077_still_makes_parents_0755(tmp_path: Path) -> None:
    """The mode is set, not left to the umask either way."""
    old = os.umask(0o077)
    try:
        prepare = tmp_path / "p" / "q" / "state"
        StateDir.open(prepare).close()
    finally:
        os.umask(old)
    assert (_mode(tmp_path / "p"), _mode(tmp_path / "p" / "q"), _mode(prepare)) == \
        (0o755, 0o755, 0o700)


def test_the_recorder_creates_its_way_0755_under_umask_000(
        tmp_path: Path, umask_000: None) -> None:
    db = _base(tmp_path) / "r" / "s" / "samples.sqlite"
    with Recorder(db):
        modes = [_mode(p) for p in (db.parent.parent, db.parent, db, Path(f"{db}-wal"),
                                    Path(f"{db}-shm"))]
    assert modes == [0o755, 0o700, 0o600, 0o600, 0o600]  # SQLite's own files as the db


# -- refusing a loose way ---------------------------------------------------------------


def test_a_parent_others_can_write_is_refused_naming_it(tmp_path: Path) -> None:
    base = _base(tmp_path)
    state = base / "n" / "x" / "y" / "state"
    StateDir.open(state).close()
    os.chmod(state.parent, 0o777)  # what a parent created 0777 under umask 000 would be
    with pytest.raises(UnsafeParent) as info:
        StateLock(state).acquire()
    assert info.value.path == state.parent and info.value.code == EX_CONFIG
    assert "writable by group or others (mode 0777) without the sticky bit" in str(info.value)
    os.chmod(state.parent, 0o1777)  # sticky, as /tmp: nobody renames what is not theirs
    StateLock(state).acquire()


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to give a directory away")
def test_a_parent_of_another_user_is_refused(tmp_path: Path) -> None:
    state = tmp_path / "n" / "state"
    state.mkdir(parents=True, mode=0o700)
    os.chown(state.parent, 12345, 12345)
    with pytest.raises(UnsafeParent, match="owned by uid 12345, neither root nor this"):
        StateDir.open(state)


def test_a_link_on_the_way_is_followed_when_ours(tmp_path: Path) -> None:
    real = tmp_path / "real"
    real.mkdir()
    (tmp_path / "via").symlink_to("real")
    with StateDir.open(tmp_path / "via" / "n" / "state") as d:
        assert d.fd is not None
    assert (real / "n" / "state").is_dir()


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to give a link away")
def test_a_link_of_another_user_on_the_way_is_refused(tmp_path: Path) -> None:
    real = tmp_path / "real"
    real.mkdir()
    via = tmp_path / "via"
    via.symlink_to(real)
    os.lchown(via, 12345, 12345)
    with pytest.raises(UnsafeParent, match="link owned by uid 12345"):
        StateDir.open(via / "state")


def test_run_refuses_a_loose_parent_with_78_in_one_line(tmp_path: Path) -> None:
    base = _base(tmp_path)
    state = base / "n" / "state"
    state.mkdir(parents=True, mode=0o700)
    os.chmod(state.parent, 0o777)
    config = write_config(tmp_path, "modbus://127.0.0.1:1")
    config.write_text(config.read_text().replace('dir = "state"', f'dir = "{state}"'))
    proc = subprocess.run([sys.executable, "-m", "compd", "run", str(config)],
                          check=False, capture_output=True, text=True, timeout=60, cwd=ROOT,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.returncode == 78, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if "state directory refused" in ln]
    assert len(lines) == 1 and str(state.parent) in lines[0], proc.stderr
    assert "writable by group or others" in lines[0]
    assert "Traceback" not in proc.stderr


# -- the swap ---------------------------------------------------------------------------


def _swap(state: Path, vict: Path) -> Path:
    """The attack: the state directory renamed away, a link to `vict` in its place."""
    stolen = state.with_name("stolen")
    state.rename(stolen)
    state.symlink_to(vict)
    return stolen


def test_a_checkpoint_after_the_swap_lands_in_the_directory_opened(tmp_path: Path) -> None:
    base = _base(tmp_path)
    state = base / "n" / "x" / "y" / "state"
    vict = _victim_dir(base)
    lock = StateLock(state)
    lock.acquire()
    try:
        save_checkpoint(state / "checkpoint.json", {"sequence": 1}, directory=lock.directory)
        stolen = _swap(state, vict)
        save_checkpoint(state / "checkpoint.json", {"sequence": 2}, directory=lock.directory)
        loaded = load_checkpoint(state / "checkpoint.json", directory=lock.directory)
    finally:
        lock.release()
    assert (vict / "checkpoint.json").read_text() == PRECIOUS
    assert sorted(p.name for p in vict.iterdir()) == ["checkpoint.json"]
    assert loaded is not None and loaded["sequence"] == 2
    assert json.loads((stolen / "checkpoint.json").read_text())["sequence"] == 2


async def test_the_running_daemon_never_writes_through_a_swapped_state_dir(
        tmp_path: Path) -> None:
    """The attack on the real daemon: the swap while it runs; its
    checkpoints (every 5 cycles and at shutdown) and its records go on in the
    directory it opened, never into the link's target. On a stepped clock with
    0.4 s requests: counted cycles, not a wall-time loop."""
    from compd.config.loader import load_config
    from drivers.sim.modbus_server import ModbusSimController
    from tests.harness import stepped_daemon

    base = _base(tmp_path)
    state = base / "n" / "x" / "y" / "state"
    vict = _victim_dir(base)
    sim = ModbusSimController()
    await sim.start()
    try:
        await sim.publish({"bearing": 20.0, "ambient": 20.0})
        config = write_config(tmp_path, sim.endpoint, checkpoint_every=5, time_scale=1.0)
        config.write_text(config.read_text().replace('dir = "state"', f'dir = "{state}"'))
        async with stepped_daemon(load_config(config)) as run:
            daemon = run.daemon
            await run.until(lambda: daemon.telemetry.complete_cycles >= 6)
            stolen = _swap(state, vict)
            swapped_at = daemon.loop.cycles
            await run.until(lambda: daemon.loop.cycles >= swapped_at + 12)
            recorder = daemon.recorder.recorder
            assert recorder is not None and recorder.alarm
            assert "no longer names the directory" in str(recorder.last_error)
            assert await run.stop() == 0
    finally:
        await sim.stop()
    assert (vict / "checkpoint.json").read_text() == PRECIOUS
    assert sorted(p.name for p in vict.iterdir()) == ["checkpoint.json"]
    final = json.loads((stolen / "checkpoint.json").read_text())
    assert final["sequence"] == daemon.loop.cycles


# -- hard links at SQLite's names -------------------------------------------------------


@pytest.mark.parametrize("suffix", ["", "-wal", "-shm", "-journal"])
def test_a_hard_link_at_a_recorder_name_is_refused_and_its_target_untouched(
        tmp_path: Path, suffix: str) -> None:
    state = tmp_path / "state"
    state.mkdir(mode=0o700)
    victim = tmp_path / "victim.bin"
    victim.write_text("precious\n")
    db = state / "samples.sqlite"
    os.link(victim, f"{db}{suffix}")
    with pytest.raises(RecorderError, match="2 hard links; refused"):
        Recorder(db).open()
    assert victim.read_text() == "precious\n"


def test_a_name_swapped_while_recording_stops_the_commits(tmp_path: Path) -> None:
    """Checked again before every commit: a hard link put in the place of -shm
    while the recorder runs is refused (rows dropped and counted, alarm)."""
    from compd.core.record import RecordRow

    state = tmp_path / "state"
    state.mkdir(mode=0o700)
    db = state / "samples.sqlite"
    victim = tmp_path / "victim.bin"
    victim.write_text("precious\n")
    row = RecordRow(seq=1, mono_s=1.0, wall_s=1.0, offset_um=0.0, model_um=0.0, state="ok",
                    valid=True, channels={"bearing": 20.0})
    rec = Recorder(db, commit_every=1)
    rec.open()
    try:
        rec.record(row)
        assert rec.committed == 1 and not rec.alarm
        shm = Path(f"{db}-shm")
        assert shm.exists()
        shm.unlink()
        os.link(victim, shm)
        rec.record(row)
        assert rec.alarm and rec.dropped == 1 and "hard links" in str(rec.last_error)
        assert victim.read_text() == "precious\n"
    finally:
        rec.close()
    assert victim.read_text() == "precious\n"


def test_names_checked_in_the_directory_are_refused_when_links(tmp_path: Path) -> None:
    with StateDir.open(tmp_path / "state") as d:
        (tmp_path / "state" / "a").symlink_to(tmp_path)
        with pytest.raises(StateDirError, match="symbolic link"):
            d.check_names(["a"])
        d.check_names(["missing"])
