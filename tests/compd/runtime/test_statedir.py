"""The state directory from the hostile side: a umask of 000, links planted at
the lock, the checkpoint's temp name, the checkpoint and the recorder, a
directory of another mode, and a state dir that is a file (refused by
`compd check` and `compd run` alike, one line, no traceback)."""

from __future__ import annotations

import os
import stat
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from compd.cli import main
from compd.runtime.checkpoint import (
    CheckpointError,
    _temp_path,
    load_checkpoint,
    save_checkpoint,
)
from compd.runtime.recorder import Recorder, RecorderError
from compd.runtime.statedir import StateDirError, prepare_state_dir
from compd.runtime.statelock import LOCK_NAME, StateLock
from tests.configs import write_config

ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture
def umask_000() -> Iterator[None]:
    old = os.umask(0)
    try:
        yield
    finally:
        os.umask(old)


def _victim(tmp_path: Path) -> Path:
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    return victim


def test_state_dir_is_created_private_under_umask_000(tmp_path: Path, umask_000: None) -> None:
    state = tmp_path / "a" / "state"
    lock = StateLock(state)
    lock.acquire()
    try:
        assert stat.S_IMODE(os.stat(state).st_mode) == 0o700
        assert stat.S_IMODE(os.stat(state / LOCK_NAME).st_mode) == 0o600
    finally:
        lock.release()
    save_checkpoint(state / "checkpoint.json", {"x": 1})
    assert stat.S_IMODE(os.stat(state / "checkpoint.json").st_mode) == 0o600


def test_planted_lock_link_is_refused_and_target_untouched(tmp_path: Path) -> None:
    state = tmp_path / "state"
    state.mkdir(mode=0o700)
    victim = _victim(tmp_path)
    (state / LOCK_NAME).symlink_to(victim)
    with pytest.raises(StateDirError, match="symbolic link"):
        StateLock(state).acquire()
    assert victim.read_text() == "precious\n"


def test_planted_hard_link_at_the_lock_is_refused(tmp_path: Path) -> None:
    state = tmp_path / "state"
    state.mkdir(mode=0o700)
    victim = _victim(tmp_path)
    os.link(victim, state / LOCK_NAME)
    with pytest.raises(StateDirError, match="hard links"):
        StateLock(state).acquire()
    assert victim.read_text() == "precious\n"


def test_planted_checkpoint_temp_link_is_removed_not_followed(tmp_path: Path) -> None:
    state = tmp_path / "state"
    state.mkdir(mode=0o700)
    victim = _victim(tmp_path)
    path = state / "checkpoint.json"
    _temp_path(path).symlink_to(victim)
    save_checkpoint(path, {"x": 2})
    assert victim.read_text() == "precious\n"
    loaded = load_checkpoint(path)
    assert loaded is not None and loaded["x"] == 2
    assert not _temp_path(path).exists()


def test_checkpoint_that_is_a_link_is_refused(tmp_path: Path) -> None:
    real = tmp_path / "elsewhere.json"
    save_checkpoint(real, {"x": 3})
    link = tmp_path / "checkpoint.json"
    link.symlink_to(real)
    with pytest.raises(CheckpointError, match="symbolic link"):
        load_checkpoint(link)


def test_checkpoint_that_is_a_device_or_huge_is_refused(tmp_path: Path) -> None:
    with pytest.raises(CheckpointError, match="not a regular file"):
        load_checkpoint(Path("/dev/zero"))


@pytest.mark.parametrize("suffix", ["", "-wal", "-shm"])
def test_recorder_refuses_planted_links(tmp_path: Path, suffix: str) -> None:
    victim = _victim(tmp_path)
    db = tmp_path / "samples.sqlite"
    Path(str(db) + suffix).symlink_to(victim)
    with pytest.raises(RecorderError, match="symbolic link"):
        Recorder(db).open()
    assert victim.read_text() == "precious\n"


def test_loose_or_foreign_state_dir_is_refused(tmp_path: Path) -> None:
    loose = tmp_path / "loose"
    loose.mkdir()
    os.chmod(loose, 0o777)
    with pytest.raises(StateDirError, match="writable by group or others"):
        prepare_state_dir(loose)
    if os.geteuid() == 0:  # root can give a directory away
        foreign = tmp_path / "foreign"
        foreign.mkdir(mode=0o700)
        os.chown(foreign, 12345, 12345)
        with pytest.raises(StateDirError, match="owned by uid 12345"):
            prepare_state_dir(foreign)
    a_file = tmp_path / "file"
    a_file.write_text("x")
    with pytest.raises(StateDirError, match="not a directory"):
        prepare_state_dir(a_file)


def test_state_dir_reached_through_a_link_is_fine(tmp_path: Path) -> None:
    """systemd's DynamicUser= makes /var/lib/NAME a link into /var/lib/private."""
    real = tmp_path / "private" / "compd"
    real.mkdir(parents=True, mode=0o700)
    link = tmp_path / "compd"
    link.symlink_to(real)
    prepare_state_dir(link)
    lock = StateLock(link)
    lock.acquire()
    lock.release()


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to give a link away")
def test_state_dir_link_of_another_user_is_refused(tmp_path: Path) -> None:
    real = tmp_path / "real"
    real.mkdir(mode=0o700)
    link = tmp_path / "state"
    link.symlink_to(real)
    os.lchown(link, 12345, 12345)
    with pytest.raises(StateDirError, match="link owned by uid 12345"):
        prepare_state_dir(link)


def test_state_dir_that_is_a_file_is_a_config_error_for_check_and_run(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = write_config(tmp_path, "modbus://127.0.0.1:1")
    (tmp_path / "state").write_text("not a dir")
    for argv in (["check", str(config)], ["run", str(config), "--once"]):
        assert main(argv) == 78
        err = capsys.readouterr().err
        assert "state.dir" in err and "not a directory" in err
        assert "Traceback" not in err


def test_run_refuses_a_loose_state_dir_with_73(tmp_path: Path) -> None:
    config = write_config(tmp_path, "modbus://127.0.0.1:1")
    state = tmp_path / "state"
    state.mkdir()
    os.chmod(state, 0o777)
    proc = subprocess.run([sys.executable, "-m", "compd", "run", str(config)],
                          check=False, capture_output=True, text=True, timeout=60, cwd=ROOT,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.returncode == 73, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if "state directory refused" in ln]
    assert lines and "writable by group or others" in lines[0]
    assert "Traceback" not in proc.stderr
