"""Checkpoints: round trip, torn/garbled files refused with a reason, and a
SIGKILL at any moment of a save leaves a complete, valid checkpoint."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from compd.errors import CompdError
from compd.runtime.checkpoint import CheckpointError, load_checkpoint, save_checkpoint

ROOT = Path(__file__).resolve().parents[3]


def _state(seq: int, n: int = 8) -> dict[str, Any]:
    return {
        "model": {"terms": {"spindle": {"x": [seq * 0.5] * n, "u_ref": 21.25}}},
        "offset_um": -3.125,
        "saved_mono_s": 1234.5,
        "sequence": seq,
        "model_sha256": "ab" * 32,
        "config_sha256": "cd" * 32,
    }


def test_round_trip_adds_version_time_and_checksum(tmp_path: Path) -> None:
    path = tmp_path / "state.json"
    before = time.time()
    save_checkpoint(path, _state(7))
    loaded = load_checkpoint(path)
    assert loaded is not None
    assert loaded["version"] == 1
    assert before - 1 <= loaded["saved_wall_s"] <= time.time() + 1
    assert len(loaded["checksum"]) == 64
    state = {k: v for k, v in loaded.items() if k not in {"version", "saved_wall_s", "checksum"}}
    assert state == _state(7)
    assert not list(tmp_path.glob(".*.tmp"))  # no temp file left behind


def test_one_top_level_key_a_line_in_sorted_order(tmp_path: Path) -> None:
    # written by json's C encoder (an indented dump takes its pure-Python one, several
    # times slower on a checkpoint of several models' delay lines), still one key a line
    path = tmp_path / "state.json"
    state = {**_state(7), "axes": {"x": {"value": 1.5, "value_model": {"x": [0.25] * 40}}},
             "note": "naïve"}
    save_checkpoint(path, state)
    lines = path.read_text(encoding="ascii").splitlines()
    assert lines[0] == "{" and lines[-1] == "}"
    keys = [json.loads("{" + line.rstrip(",") + "}").popitem() for line in lines[1:-1]]
    assert [k for k, _ in keys] == sorted(state.keys() | {"version", "saved_wall_s", "checksum"})
    assert dict(keys)["axes"] == state["axes"] and dict(keys)["note"] == "naïve"
    assert load_checkpoint(path) == dict(keys)


def test_missing_is_none(tmp_path: Path) -> None:
    assert load_checkpoint(tmp_path / "none.json") is None


def test_overwrite_replaces(tmp_path: Path) -> None:
    path = tmp_path / "state.json"
    save_checkpoint(path, _state(1))
    save_checkpoint(path, _state(2))
    loaded = load_checkpoint(path)
    assert loaded is not None and loaded["sequence"] == 2


def _load_error(path: Path) -> CheckpointError:
    with pytest.raises(CheckpointError) as info:
        load_checkpoint(path)
    assert isinstance(info.value, CompdError)
    assert info.value.path == path
    assert str(path) in str(info.value)
    return info.value


def test_every_truncation_is_detected(tmp_path: Path) -> None:
    good = tmp_path / "good.json"
    save_checkpoint(good, _state(3))
    data = good.read_bytes()
    torn = tmp_path / "torn.json"
    for cut in range(len(data)):
        torn.write_bytes(data[:cut])
        err = _load_error(torn)
        assert err.reason  # e.g. "empty file (torn write)" or "not valid JSON ..."
    torn.write_bytes(b"")
    assert "empty" in _load_error(torn).reason


def test_garbled_bytes_are_detected(tmp_path: Path) -> None:
    good = tmp_path / "good.json"
    save_checkpoint(good, _state(4))
    data = bytearray(good.read_bytes())
    bad = tmp_path / "bad.json"
    rng = random.Random(5)
    for _ in range(200):
        flipped = bytearray(data)
        i = rng.randrange(len(flipped))
        flipped[i] ^= 1 << rng.randrange(8)
        bad.write_bytes(bytes(flipped))
        try:
            loaded = load_checkpoint(bad)
        except CheckpointError as err:
            assert err.reason
            continue
        # a flip in insignificant whitespace changes nothing the state holds
        assert loaded is not None
        assert {k: v for k, v in loaded.items()
                if k not in {"version", "saved_wall_s", "checksum"}} == _state(4)


def test_a_changed_value_fails_the_checksum(tmp_path: Path) -> None:
    path = tmp_path / "state.json"
    save_checkpoint(path, _state(5))
    obj = json.loads(path.read_text())
    obj["offset_um"] = 99.0
    path.write_text(json.dumps(obj))
    assert "checksum" in _load_error(path).reason


def test_wrong_version_and_shapes(tmp_path: Path) -> None:
    path = tmp_path / "state.json"
    save_checkpoint(path, _state(5))
    obj = json.loads(path.read_text())
    obj["version"] = 2
    path.write_text(json.dumps(obj))
    assert "version" in _load_error(path).reason
    path.write_text("[1, 2]")
    assert "object" in _load_error(path).reason
    path.write_text('{"version": 1, "saved_wall_s": 1.0}')
    assert "checksum" in _load_error(path).reason
    path.write_bytes(b"\xff\xfe\x00garbage")
    assert "UTF-8" in _load_error(path).reason
    path.write_text('{"version": 1, "x": NaN}')
    assert "non-finite" in _load_error(path).reason


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_non_finite_refused_at_save(tmp_path: Path, bad: float) -> None:
    path = tmp_path / "state.json"
    save_checkpoint(path, _state(1))
    state = _state(2)
    state["model"]["terms"]["spindle"]["x"][3] = bad
    with pytest.raises(CheckpointError) as info:
        save_checkpoint(path, state)
    assert "non-finite" in info.value.reason
    loaded = load_checkpoint(path)  # the old checkpoint is untouched
    assert loaded is not None and loaded["sequence"] == 1


def test_unstorable_and_reserved_refused(tmp_path: Path) -> None:
    path = tmp_path / "state.json"
    with pytest.raises(CheckpointError, match="JSON"):
        save_checkpoint(path, {"x": object()})
    with pytest.raises(CheckpointError, match="reserved"):
        save_checkpoint(path, {"version": 3})
    assert not path.exists()


_SAVER = """
import sys
from pathlib import Path
from compd.runtime.checkpoint import save_checkpoint
path = Path(sys.argv[1])
n = 20000
seq = 1
save_checkpoint(path, {"sequence": seq, "x": [seq] * n, "tail": seq})
sys.stdout.write("go\\n"); sys.stdout.flush()  # one complete save, then kill at random
while True:
    seq += 1
    save_checkpoint(path, {"sequence": seq, "x": [seq] * n, "tail": seq})
"""


def test_sigkill_during_saves_leaves_a_complete_checkpoint(tmp_path: Path) -> None:
    path = tmp_path / "state.json"
    rng = random.Random(11)
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    last_seq = 0
    kills = 30
    for _ in range(kills):
        proc = subprocess.Popen([sys.executable, "-c", _SAVER, str(path)],
                                stdout=subprocess.PIPE, env=env, cwd=ROOT)
        assert proc.stdout is not None
        assert proc.stdout.readline() == b"go\n"
        time.sleep(rng.uniform(0.0, 0.05))
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        proc.stdout.close()
        # a busy machine may kill it before its next save completes: then the file
        # holds an earlier one, complete (each run saved once before "go")
        loaded = load_checkpoint(path)
        assert loaded is not None
        seq = loaded["sequence"]
        assert loaded["x"] == [seq] * 20000 and loaded["tail"] == seq
        last_seq = seq
    assert last_seq > 0
