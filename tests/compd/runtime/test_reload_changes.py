"""`reload_succeeded` names the config keys a reload changed, apart from what it
restarted: a changed slew limit restarts nothing, and is still a change."""

from __future__ import annotations

from pathlib import Path

from compd.config.loader import load_config
from compd.runtime.reload import prepare
from tests.configs import write_config


def test_a_changed_slew_limit_is_named_though_nothing_restarts(tmp_path: Path) -> None:
    path = write_config(tmp_path, "modbus://127.0.0.1:5020", slew_um_s=1.0)
    old = load_config(path)
    write_config(tmp_path, "modbus://127.0.0.1:5020", slew_um_s=0.5, checkpoint_every=7)
    _, changes = prepare(old)
    assert changes.keys == ("output.slew_um_s", "state.checkpoint_every")
    assert changes.names() == []  # the model, driver and outputs carry over


def test_an_unchanged_file_changes_nothing(tmp_path: Path) -> None:
    old = load_config(write_config(tmp_path, "modbus://127.0.0.1:5020"))
    _, changes = prepare(old)
    assert changes.keys == () and changes.names() == []
