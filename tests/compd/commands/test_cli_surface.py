"""What every `compd` command shows a person: the
version, help text on every option and an examples section, one exit-code
table, and one reader for config and model files in `run` and `check`."""

from __future__ import annotations

import argparse
import asyncio
import re
from pathlib import Path

import pytest
import structlog

from compd import __version__
from compd.cli import COMMANDS, build_parser, main
from compd.config.loader import load_config
from compd.infiles import load_model
from compd.runtime.daemon import Daemon
from compd.runtime.sdnotify import Notifier
from compd.sysexits import EX_CONFIG, EX_DATAERR, EX_NOINPUT, EX_USAGE
from drivers.sim.modbus_server import ModbusSimController
from tests.configs import write_config
from tests.shipped import EXAMPLES, LIBRARY, PACKAGES_ROOT


def _subparsers() -> dict[str, argparse.ArgumentParser]:
    for action in build_parser()._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    raise AssertionError("no subcommands")


def test_version_is_printed(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        main(["--version"])
    assert info.value.code == 0
    assert capsys.readouterr().out.strip() == f"compd {__version__}"


def test_every_option_of_every_command_has_help_text() -> None:
    missing = [f"{name} {' '.join(a.option_strings) or a.dest}"
               for name, sub in _subparsers().items() for a in sub._actions
               if not a.help and not isinstance(a, argparse._HelpAction)]
    assert missing == []


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_every_command_has_an_examples_section(name: str,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main([name, "--help"])
    out = capsys.readouterr().out
    assert "examples:" in out and f"compd {name}" in out.split("examples:")[1]
    assert "%%" not in out  # replay's "fit %" printed as "fit %%" once


def test_check_refuses_connect_on_a_model(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check", "sp2", "--connect"]) == EX_USAGE
    err = capsys.readouterr().err
    assert "--connect" in err and err.count("\n") == 1


def test_a_config_that_is_not_utf8_is_named_the_same_by_check_and_run(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "compd.toml"
    bad.write_bytes('[machine]\nname = "Drehmaschine Nr. 3 – Halle Süd"\n'.encode("latin-1",
                                                                               "replace"))
    assert main(["check", str(bad)]) == EX_DATAERR
    check_err = capsys.readouterr().err
    assert main(["run", str(bad), "--dry-run", "--once"]) == EX_CONFIG
    run_err = capsys.readouterr().err
    for err in (check_err, run_err):
        assert "not UTF-8 text" in err and "Traceback" not in err and err.count("\n") == 1
    assert "model file" not in check_err


def test_check_on_a_missing_file_does_not_call_it_a_model_file(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check", str(tmp_path / "compd.toml")]) == EX_NOINPUT
    err = capsys.readouterr().err
    assert "model or config file" in err and "No such file" in err


def test_check_reads_a_config_and_a_model_once_each(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check", str(EXAMPLES / "modbus.toml")]) == 0
    assert ": OK" in capsys.readouterr().out
    assert main(["check", str(LIBRARY / "sp2.toml")]) == 0
    assert "term" in capsys.readouterr().out


def test_exit_codes_are_declared_once_in_sysexits() -> None:
    """No module assigns or returns a sysexits number itself (health had its
    own EX_USAGE = 64)."""
    pattern = re.compile(r"(?:\bEX_[A-Z]+\s*=|\breturn|exit\()\s*(64|65|66|73|74|75|78)\b")
    offenders = [f"{p.relative_to(PACKAGES_ROOT)}:{n}"
                 for root in ("compd", "drivers", "models")
                 for p in (PACKAGES_ROOT / root).rglob("*.py") if p.name != "sysexits.py"
                 for n, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1)
                 if pattern.search(line)]
    assert offenders == []


def test_usage_errors_exit_64(capsys: pytest.CaptureFixture[str]) -> None:
    for argv in (["check"], ["fit", "x.csv"], ["--nope"], ["step", "sp2", "--hours", "x"]):
        with pytest.raises(SystemExit) as info:
            main(argv)
        assert info.value.code == EX_USAGE, argv
    capsys.readouterr()


def test_a_fitted_model_names_the_compd_version(tmp_path: Path) -> None:
    lines = [f"{k},{25 + k / 100:.2f},{k / 10 + (k % 5) / 50:.3f}" for k in range(300)]
    rec = tmp_path / "rec.csv"
    rec.write_text("time_s,bearing,dz_um\n" + "\n".join(lines) + "\n", encoding="utf-8")
    out = tmp_path / "m.toml"
    assert main(["fit", str(rec), "--column", "dz_um", "--term", "bearing", "--orders", "1-1",
                 "-o", str(out)]) == 0
    assert load_model(out).provenance["compd_version"] == __version__


async def test_the_start_log_line_names_the_version(tmp_path: Path) -> None:
    sim = ModbusSimController()
    await sim.start()
    try:
        await sim.publish({"bearing": 20.0, "ambient": 20.0})
        cfg = load_config(write_config(tmp_path, sim.endpoint))
        daemon = Daemon(cfg, notifier=Notifier(None))
        with structlog.testing.capture_logs() as logs:
            task = asyncio.create_task(daemon.run())
            for _ in range(2000):
                if daemon.loop.cycles >= 2:
                    break
                await asyncio.sleep(0.005)
            daemon.request_stop()
            assert await task == 0
    finally:
        await sim.stop()
    start = next(e for e in logs if e["event"] == "daemon_starting")
    assert start["version"] == __version__


def test_one_csv_reader_for_records() -> None:
    """drivers/sim/csvlog.py had a second, looser reader (no sampling or cell
    checks): records are parsed in compd/offline/csvstream.py only."""
    parsers = re.compile(r"csv\.(reader|DictReader)\(|loadtxt\(|genfromtxt\(|def read_record\(")
    found = sorted(str(p.relative_to(PACKAGES_ROOT))
                   for root in ("compd", "drivers", "models")
                   for p in (PACKAGES_ROOT / root).rglob("*.py")
                   if parsers.search(p.read_text("utf-8")))
    assert found == ["compd/offline/csvstream.py", "compd/offline/records.py"]
