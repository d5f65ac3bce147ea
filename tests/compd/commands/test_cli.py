"""The command line itself: every subcommand is reachable and documents itself."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from compd.cli import COMMANDS, build_parser, command_named, main


def test_top_level_help_lists_every_command(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        main(["--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    for name in COMMANDS:
        assert name in out


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_each_command_has_help(name: str, capsys: pytest.CaptureFixture[str]) -> None:
    parser = build_parser()
    with pytest.raises(SystemExit) as info:
        parser.parse_args([name, "--help"])
    assert info.value.code == 0
    assert capsys.readouterr().out.strip()


def test_a_command_loads_only_its_own_module() -> None:
    """`compd run` builds run's parser alone: no other command's module (nor what
    it imports at the top) is loaded in the process."""
    probe = ("import json, sys\nfrom compd.cli import main\n"
             "try:\n    main(['run', '--help'])\nexcept SystemExit:\n    pass\n"
             "print(json.dumps(sorted(m for m in sys.modules if m.startswith('compd.commands.'))),"
             " file=sys.stderr)")
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          timeout=60, check=True)
    assert json.loads(proc.stderr.strip().splitlines()[-1]) == ["compd.commands.run"]
    assert "dry-run" in proc.stdout


@pytest.mark.parametrize(("argv", "named"), [
    (["run", "x.toml"], "run"), (["--version"], None), (["-h", "check"], "check"),
    (["bogus", "run"], None), (["--", "run"], None), ([], None)])
def test_the_command_a_line_names(argv: list[str], named: str | None) -> None:
    assert command_named(argv) == named


def test_a_wrong_command_still_lists_every_command(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        main(["bogus", "run"])
    assert info.value.code == 64
    err = capsys.readouterr().err
    assert "invalid choice: 'bogus'" in err
    for name in COMMANDS:
        assert repr(name) in err
