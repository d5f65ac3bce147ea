"""`compd check` refuses what `compd run` refuses before it connects (one
validation path: `compd.runtime.driver_setup.check_driver` constructs the
driver as run does), and `compd sim --protocol focas` names the stand-in
library a daemon config needs."""

from __future__ import annotations

import asyncio
import signal
import sys
from pathlib import Path

import pytest

from compd.cli import main
from compd.commands.sim import describe
from compd.sysexits import EX_CONFIG
from drivers.sim.fwlib_build import build_standin
from drivers.sim.registry import make_sim_controller
from tests.configs import write_config
from tests.shipped import EXAMPLES

ROOT = Path(__file__).resolve().parents[3]
FOCAS = EXAMPLES / "focas.toml"


def _focas_config(tmp_path: Path, library: str) -> Path:
    return write_config(tmp_path, base="focas", filename="focas.toml", library_path=library)


@pytest.mark.parametrize("command", ["check", "run"])
def test_check_and_run_refuse_a_missing_focas_library_alike(
        command: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _focas_config(tmp_path, str(tmp_path / "no-such-libfwlib32.so"))
    assert main([command, str(path)]) == EX_CONFIG
    out, err = capsys.readouterr()
    assert "OK" not in out
    [line] = err.strip().splitlines()
    assert "controller.focas.library_path" in line and "is not a file" in line


def test_the_shipped_focas_example_is_refused_until_its_library_is_named(
        capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check", str(FOCAS)]) == EX_CONFIG
    assert "'/usr/local/lib/libfwlib32.so' is not a file" in capsys.readouterr().err


def test_check_says_ok_with_the_stand_in_library(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    path = _focas_config(tmp_path, str(build_standin()))
    assert main(["check", str(path)]) == 0, capsys.readouterr().err
    assert "OK" in capsys.readouterr().out


def test_sim_json_names_the_focas_stand_in_library() -> None:
    sim = make_sim_controller("focas")
    info = describe(sim)
    library = info["focas"]["library_path"]  # type: ignore[index]
    assert Path(library).is_file() and Path(library).is_absolute()
    assert "focas" not in describe(make_sim_controller("modbus"))


async def test_sim_prints_the_focas_stand_in_library(tmp_path: Path) -> None:
    stderr = (tmp_path / "stderr.txt").open("wb")
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "compd", "sim", "--protocol", "focas", cwd=ROOT,
        stdout=asyncio.subprocess.PIPE, stderr=stderr)
    stderr.close()
    lines: list[str] = []
    try:
        assert proc.stdout is not None
        while not lines or "Ctrl-C" not in lines[-1]:
            raw = await asyncio.wait_for(proc.stdout.readline(), 60.0)
            assert raw, (tmp_path / "stderr.txt").read_text()
            lines.append(raw.decode())
    finally:
        proc.send_signal(signal.SIGTERM)
        await asyncio.wait_for(proc.wait(), 30.0)
    [line] = [x for x in lines if "library_path" in x]
    assert line.split()[1] == str(build_standin())  # the file the sim serves with
