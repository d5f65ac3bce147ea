"""`compd health` reads the checkpoint with the daemon's own reader
(`load_checkpoint`): what the daemon would refuse to restore is no evidence
of a healthy daemon either (a checkpoint whose checksum fails is none)."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import pytest

from compd.cli import main
from compd.runtime.checkpoint import (
    CHECKPOINT_NAME,
    CheckpointError,
    load_checkpoint,
    save_checkpoint,
)
from compd.runtime.liveness import boot_id
from compd.runtime.startup import checkpoint_path


def _fresh(state: Path) -> Path:
    path = state / CHECKPOINT_NAME
    save_checkpoint(path, {"sequence": 9, "last_complete_wall_s": time.time(),
                           "last_complete_mono_s": time.monotonic(), "boot_id": boot_id()})
    return path


def _health(capsys: pytest.CaptureFixture[str], state: Path) -> tuple[int, str]:
    rc = main(["health", "--state-dir", str(state)])
    out = capsys.readouterr().out
    assert out.count("\n") == 1, out
    return rc, out.strip()


def test_an_edited_checkpoint_is_refused_by_health_as_by_the_daemon(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _fresh(tmp_path)
    assert _health(capsys, tmp_path)[0] == 0
    doc = json.loads(path.read_text())
    doc["sequence"] = 10  # valid JSON, every key there: only the checksum tells
    path.write_text(json.dumps(doc))
    with pytest.raises(CheckpointError, match="checksum mismatch"):
        load_checkpoint(path)
    rc, line = _health(capsys, tmp_path)
    assert rc == 1
    assert line == (f"unhealthy: state dir {tmp_path}: checkpoint unreadable "
                    "(checksum mismatch (corrupt or edited))")


def test_a_checkpoint_of_another_format_is_refused_with_the_daemons_reason(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A JSON object with a fresh stamp but no version or checksum: health used
    to call it healthy; the daemon never restores it."""
    (tmp_path / CHECKPOINT_NAME).write_text(json.dumps(
        {"last_complete_wall_s": time.time(), "last_complete_mono_s": time.monotonic(),
         "boot_id": boot_id()}))
    rc, line = _health(capsys, tmp_path)
    assert rc == 1 and line.endswith("checkpoint unreadable (wrong version None "
                                     "(this compd reads version 1))")


def test_a_linked_checkpoint_is_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    target = _fresh(elsewhere)
    state = tmp_path / "state"
    state.mkdir()
    (state / CHECKPOINT_NAME).symlink_to(target)
    rc, line = _health(capsys, state)
    assert rc == 1 and "symbolic link" in line


def test_the_daemon_and_health_read_the_same_file_name() -> None:
    class Cfg:
        state_dir = Path("/var/lib/compd")

    assert checkpoint_path(Cfg()) == Path("/var/lib/compd") / CHECKPOINT_NAME  # type: ignore[arg-type]  # only state_dir is read


@pytest.mark.skipif(os.geteuid() != 0, reason="changing a file's owner needs root")
def test_health_run_by_root_reads_the_daemons_checkpoint_not_a_strangers(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`sudo compd health --state-dir /var/lib/compd` (deploy/systemd/README.md):
    the checkpoint is the state directory owner's, not root's; one of another
    owner was planted and proves nothing."""
    daemon_uid, stranger_uid = 4242, 4343
    state = tmp_path / "state"
    state.mkdir()
    path = _fresh(state)
    os.chown(state, daemon_uid, daemon_uid)
    os.chown(path, daemon_uid, daemon_uid)
    assert _health(capsys, state)[0] == 0
    os.chown(path, stranger_uid, stranger_uid)
    rc, line = _health(capsys, state)
    assert rc == 1 and f"owned by uid {stranger_uid}" in line


def test_an_offset_flapping_in_and_out_of_force_saves_once_a_window_and_stays_red(
        tmp_path: Path) -> None:
    """Going out of force saves at once (health --state-dir sees it as --url
    does); flapping saves no more than once a checkpoint_every window out of turn,
    and the saved cause stays the one out of force until a window passes in force."""
    from types import SimpleNamespace
    from typing import Any, cast

    from compd.core.faults import FaultState
    from compd.core.health import Cause
    from compd.runtime.sinks.checkpoint import CheckpointSink

    every = 10
    cfg = SimpleNamespace(raw=SimpleNamespace(state=SimpleNamespace(checkpoint_every=every)),
                          state_dir=tmp_path, model_sha256="m", config_sha256="c")
    saved: list[object] = []
    sink = CheckpointSink(dry_run=False, journal=cast(Any, None))
    state = cast(Any, SimpleNamespace(export_state=lambda: {"sequence": len(saved)}))

    def cycle(seq: int, cause: Cause) -> None:
        row = SimpleNamespace(state=FaultState.OK, cause=cause, healthy=cause.healthy,
                              sequence=seq, in_force=False, wall_s=1000.0 + seq)
        if sink.note(cast(Any, SimpleNamespace(row=row, cfg=cfg, mono_s=0.0))):
            sink.save(cast(Any, cfg), state)
            doc = load_checkpoint(tmp_path / CHECKPOINT_NAME)
            assert doc is not None
            saved.append(doc["last_cause"])

    cycle(1, Cause.IN_FORCE)
    assert saved == []
    cycle(2, Cause.AT_LIMIT)  # out of force: saved at once
    assert saved == ["at_limit"]
    for seq in range(3, 40):  # flapping every cycle
        cycle(seq, Cause.AT_LIMIT if seq % 2 else Cause.IN_FORCE)
    # only the window's own saves, each naming the cause out of force
    assert saved == ["at_limit"] * 4
    for seq in range(40, 61):  # in force from here: the window to 40 was not, then green
        cycle(seq, Cause.IN_FORCE)
    assert saved == ["at_limit"] * 5 + ["in_force"] * 2, saved
