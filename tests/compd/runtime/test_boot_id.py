"""The boot id every checkpoint stamps is read from the kernel once per process."""

from __future__ import annotations

from pathlib import Path

import pytest

from compd.runtime import liveness


def test_boot_id_is_read_once(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "boot_id"
    path.write_text("first-boot\n")
    monkeypatch.setattr(liveness, "BOOT_ID_PATH", str(path))
    assert liveness.boot_id() == "first-boot"
    path.write_text("changed\n")  # a second read would see this
    assert liveness.boot_id() == "first-boot"
    path.unlink()
    assert liveness.boot_id() == "first-boot"


def test_a_failed_read_is_not_kept(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "boot_id"
    monkeypatch.setattr(liveness, "BOOT_ID_PATH", str(path))
    assert liveness.boot_id() is None  # no such file (yet)
    path.write_text("late-boot\n")
    assert liveness.boot_id() == "late-boot"
