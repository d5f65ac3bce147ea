"""`.ci/run` runs the README's test command exactly, as a line of its own.

CI's verdict is about what a newcomer types: if the two drifted apart, a green CI
would say nothing about the README's command.
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _readme_test_command() -> str:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text.split("Set up and run the tests:", 1)[1]
    block = re.search(r"```sh\n(.*?)```", section, re.S)
    assert block is not None, "README: no sh block after 'Set up and run the tests:'"
    (line,) = [ln for ln in block.group(1).splitlines() if ln.strip()]
    return line.strip()


def test_ci_run_has_the_readme_test_command_as_a_line() -> None:
    command = _readme_test_command()
    assert "pytest" in command and "pip install" in command
    lines = [ln.strip() for ln in (ROOT / ".ci" / "run").read_text(encoding="utf-8").splitlines()]
    assert command in lines


def test_the_test_command_installs_no_more_than_the_tests_need() -> None:
    """The README's command installs the `test` extra; the checks' tools (ruff, mypy,
    import-linter, build) are `.ci/run`'s own step after it."""
    assert "'.[test]'" in _readme_test_command()
