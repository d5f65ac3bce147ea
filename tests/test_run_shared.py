"""`tests.run_shared.made_once`: made once a run, a failed making retried."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.run_shared import made_once


def test_the_folder_is_made_once_and_a_failed_making_is_tried_again(
        tmp_path_factory: pytest.TempPathFactory) -> None:
    calls: list[Path] = []

    def make(folder: Path) -> None:
        calls.append(folder)
        (folder / "x.txt").write_text("x")

    first = made_once(tmp_path_factory, "once-test", make)
    again = made_once(tmp_path_factory, "once-test", make)
    assert first == again and calls == [first] and (first / "x.txt").read_text() == "x"

    def broken(folder: Path) -> None:
        calls.append(folder)
        raise RuntimeError("no disk")

    for _ in range(2):
        with pytest.raises(RuntimeError, match="no disk"):
            made_once(tmp_path_factory, "once-broken", broken)
    assert len(calls) == 3  # the broken one was tried each time it was asked for
