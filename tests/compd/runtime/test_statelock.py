"""One daemon per state directory: a second process is refused at once with
the directory and the holder's pid; a killed holder leaves no stale lock."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from compd.errors import CompdError
from compd.runtime.statelock import StateLock, StateLocked

ROOT = Path(__file__).resolve().parents[3]
ENV = dict(os.environ, PYTHONPATH=str(ROOT))

_HOLDER = """
import sys, time
from pathlib import Path
from compd.runtime.statelock import StateLock
lock = StateLock(Path(sys.argv[1]))
lock.acquire()
sys.stdout.write("held\\n"); sys.stdout.flush()
time.sleep(60)
"""

_TRY = """
import sys
from pathlib import Path
from compd.runtime.statelock import StateLock, StateLocked
try:
    StateLock(Path(sys.argv[1])).acquire()
except StateLocked as exc:
    print("refused", exc.holder_pid, exc)
    sys.exit(3)
print("acquired")
"""


def _hold(state_dir: Path) -> subprocess.Popen[bytes]:
    proc = subprocess.Popen([sys.executable, "-c", _HOLDER, str(state_dir)],
                            stdout=subprocess.PIPE, env=ENV, cwd=ROOT)
    assert proc.stdout is not None
    assert proc.stdout.readline() == b"held\n"
    return proc


def _kill(proc: subprocess.Popen[bytes]) -> None:
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    if proc.stdout is not None:
        proc.stdout.close()


def test_second_process_refused_naming_dir_and_pid(tmp_path: Path) -> None:
    state_dir = tmp_path / "state"
    holder = _hold(state_dir)
    try:
        with pytest.raises(StateLocked) as info:
            StateLock(state_dir).acquire()
        err = info.value
        assert isinstance(err, CompdError)
        assert err.holder_pid == holder.pid
        assert str(state_dir) in str(err) and str(holder.pid) in str(err)
        # and a separate process is refused the same way (exit 3, not a hang)
        out = subprocess.run([sys.executable, "-c", _TRY, str(state_dir)], env=ENV,
                             cwd=ROOT, capture_output=True, timeout=30, check=False)
        assert out.returncode == 3, out
        assert f"refused {holder.pid}".encode() in out.stdout
    finally:
        _kill(holder)


def test_lock_released_when_holder_is_killed(tmp_path: Path) -> None:
    state_dir = tmp_path / "state"
    holder = _hold(state_dir)
    _kill(holder)
    lock = StateLock(state_dir)
    lock.acquire()
    assert lock.held
    assert (state_dir / "compd.lock").read_text().strip() == str(os.getpid())
    lock.release()
    assert not lock.held


def test_context_manager_and_reacquire(tmp_path: Path) -> None:
    with StateLock(tmp_path) as lock:
        assert lock.held
        with pytest.raises(StateLocked) as info:  # a second open in this process too
            StateLock(tmp_path).acquire()
        assert info.value.holder_pid == os.getpid()
        lock.acquire()  # idempotent while held
    assert not lock.held
    out = subprocess.run([sys.executable, "-c", _TRY, str(tmp_path)], env=ENV, cwd=ROOT,
                         capture_output=True, timeout=30, check=False)
    assert out.returncode == 0 and b"acquired" in out.stdout
    lock.release()  # idempotent when not held
